"""The box filter every stage shares: window sums over (2ry + 1) x (2rx + 1) pixels of every plane.

Valid-only, as the tiling contract wants: C x H x W in, C x (H - 2ry) x (W - 2rx) out, output pixel
(i, j) <-> input (i + ry, j + rx). The device path (``enqueue_box``, clisp/modules/common/box.cl) sums
rows first, then columns, each from 0 in order k = 0 .. 2r; ``box_sums`` is the float64 reference.

>>> import numpy as np
>>> box_sums(np.arange(12.0).reshape(1, 3, 4), 1, 1).tolist()
[[[45.0, 54.0]]]
"""
from __future__ import annotations

import numpy as np

from ...errors import ClispError
from ...engine.runtime import DeviceImage, Runtime


def box_sums(x: np.ndarray, ry: int, rx: int) -> np.ndarray:
    """Window sums of every plane of x (C x H x W, any float): C x (H - 2ry) x (W - 2rx), float64."""
    x = np.asarray(x, dtype=np.float64)
    h, w = x.shape[-2] - 2 * ry, x.shape[-1] - 2 * rx
    rows = sum(x[..., :, k:k + w] for k in range(2 * rx + 1))
    return sum(rows[..., k:k + h, :] for k in range(2 * ry + 1))


def enqueue_box(rt: Runtime, src: DeviceImage, ry: int, rx: int, scale: float = 1.0,
                release_src: bool = False) -> DeviceImage:
    """Window sums of every plane of src on the device (box_rows, then box_cols), times ``scale``
    (applied once, on the last pass: 1 gives sums, 1 / count a mean). A zero radius skips its pass;
    with both zero the source itself is returned (scale must then be 1). ``release_src``: give src
    back to the pool once read (never the returned image). One program per radius (BOX_R)."""
    c, h, w = src.channels, src.height, src.width
    if ry < 0 or rx < 0 or h - 2 * ry < 1 or w - 2 * rx < 1:
        raise ClispError(f"box sums of radius ({ry}, {rx}) need more than {h} x {w} pixels")
    if not (ry or rx) and scale != 1.0:
        raise ClispError("a box of radius 0 cannot scale its input")
    cur = src
    if rx:
        dst = rt.acquire(c, h, w - 2 * rx)
        rt.launch_named("box", "box_rows", w - 2 * rx, c * h,
                        dict(src=cur, dst=dst, in_w=w, out_w=w - 2 * rx, scale=1.0 if ry else scale, rows=c * h),
                        {"BOX_R": int(rx)}, inward=True)
        cur, w = dst, w - 2 * rx
    if ry:
        dst = rt.acquire(c, h - 2 * ry, w)
        rt.launch_named("box", "box_cols", w, c * (h - 2 * ry),
                        dict(src=cur, dst=dst, w=w, in_h=h, out_h=h - 2 * ry, scale=scale, rows=c * (h - 2 * ry)),
                        {"BOX_R": int(ry)}, inward=True)
        if cur is not src:
            rt.release(cur)
        cur = dst
    if release_src and cur is not src:
        rt.release(src)
    return cur
