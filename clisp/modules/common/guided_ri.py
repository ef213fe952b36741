"""Host side of clisp/modules/common/guided_ri.cl: the masked guided filter of the residual-interpolation Bayer demosaics
(RI, MLRI, ARI) on the device, the building block of an OpenCL port of clisp.modules.demosaic_ari.reference.

Reference: ``bayer_ri.guided_filter`` (float64, mirrored borders). Here the filter follows the project's
tiling convention: the inputs are one padded window, the output is its interior, and the borders are
the caller's business (a tile's context, or a mirror-padded image):

    guide x, target y, mask m: H x W float32 planes (any units; ARI: 8-bit values, 0..255)
    window ("box", ry, rx): the (2ry+1) x (2rx+1) rectangle
    output q: (H - 4ry) x (W - 4rx) float32, q[i, j] <-> input pixel (i + 2ry, j + 2rx)

Halo 2ry along y, 2rx along x: window sums of the six masked products (ry, rx), then window sums of
the coefficients (ry, rx). Equal to the reference's interior on any array that contains the window,
within float32 rounding (tests/test_guided_filter_cl.py states the measured bound).

    n = max(sum m, 1); mean_x = sum(m x)/n, mean_y, var_x = sum(m x^2)/n - mean_x^2, var_y, cov
    a = cov / (var_x + eps), b = mean_y - a mean_x           (per window)
    plain:    q = mean(a) x + mean(b)                          (means over every pixel of the window)
    weighted: q = (sum(a w) x + sum(b w)) / (sum w + 1e-4),   w = 1 / max(sqrt(a^2 var_x - 2a cov + var_y), 1e-3)

The weighted form is ARI's (1 / RMSE of each window's fit); its floors are in 8-bit units, like eps.
Kernels: gf_row_moments -> gf_col_coefficients -> box_x, box_y -> gf_apply (statistics centred on each
window's centre pixel, so float32 variances cancel only at the scale of the local spread; a zero radius
skips its box pass). ``centred=False``: gf_products -> box_x, box_y -> gf_coefficients instead (plain
sums of the six masked products, ~1e-7 E[x^2] of cancellation: 100x larger errors on noisy ramps).
Temporaries come from the pool and go back. MLRI's Laplacian slope, the line-pair fits sharing one set
of window sums and the diagonal windows are in clisp/modules/demosaic_ari/demosaic_ari.cl (clisp.modules.demosaic_ari.stage), which uses
box_x / box_y from here.
"""
from __future__ import annotations

import numpy as np

from ...errors import ClispError
from ...engine.runtime import DeviceImage, Runtime, launch_exact

Window = tuple[str, int, int]
i32, f32 = np.int32, np.float32
"""Kernel argument types."""


def _kernel(rt: Runtime, name: str, masked: bool = True, weighted: bool = False) -> object:
    return rt.kernel("guided_ri", name, {"GF_MASKED": int(masked), "GF_WEIGHTED": int(weighted)})


def _radii(window: Window) -> tuple[int, int]:
    kind, ry, rx = window
    if kind != "box" or ry < 0 or rx < 0:
        raise ClispError(f"device guided filter: only ('box', ry, rx) windows, got {window!r}")
    return int(ry), int(rx)


def _plane_base(image: DeviceImage, plane: int) -> np.int32:
    if not 0 <= plane < image.channels:
        raise ClispError(f"plane {plane} of a {image.channels}-plane image")
    return i32(plane * image.height * image.width)


def enqueue_box(rt: Runtime, src: DeviceImage, ry: int, rx: int, release_src: bool = False,
                per_radius: bool = False) -> DeviceImage:
    """Window sums over (2ry+1) x (2rx+1) of every plane of src (box_x then box_y): C x H x W ->
    C x (H - 2ry) x (W - 2rx), output (i, j) <-> input (i + ry, j + rx). Halo ry, rx. A zero radius
    skips its pass; with both zero the source itself is returned. ``release_src``: give src back to
    the pool once read (never the returned image). ``per_radius``: one program per radius (GF_BOX_R:
    the sum unrolls and PoCL vectorises it; for callers with few distinct radii, e.g. ARI)."""
    c, h, w = src.channels, src.height, src.width
    if h - 2 * ry < 1 or w - 2 * rx < 1:
        raise ClispError(f"box sums of radius ({ry}, {rx}) need more than {h} x {w} pixels")
    cur = src
    if rx:
        dst = rt.acquire(c, h, w - 2 * rx)
        launch_exact(rt, rt.kernel("guided_ri", "box_x", {"GF_BOX_R": rx} if per_radius else None), w - 2 * rx, c * h, cur.buffer, dst.buffer, i32(rx), i32(w),
                     i32(w - 2 * rx))
        cur, w = dst, w - 2 * rx
    if ry:
        dst = rt.acquire(c, h - 2 * ry, w)
        launch_exact(rt, rt.kernel("guided_ri", "box_y", {"GF_BOX_R": ry} if per_radius else None), w, c * (h - 2 * ry), cur.buffer, dst.buffer, i32(ry), i32(w),
                     i32(h), i32(h - 2 * ry))
        if cur is not src:
            rt.release(cur)
        cur = dst
    if release_src and cur is not src:
        rt.release(src)
    return cur


def enqueue_products(rt: Runtime, guide: DeviceImage, target: DeviceImage, mask: DeviceImage | None,
                     planes: tuple[int, int, int] = (0, 0, 0)) -> DeviceImage:
    """gf_products: 6 x H x W planes m, m x, m y, m x^2, m y^2, m x y (m = 1 where mask is None) of
    plane planes[0] of guide (x), planes[1] of target (y), planes[2] of mask, all H x W. Halo 0."""
    h, w = guide.height, guide.width
    for name, image in (("target", target), ("mask", mask)):
        if image is not None and (image.height, image.width) != (h, w):
            raise ClispError(f"device guided filter: {name} is {image.height} x {image.width}, guide {h} x {w}")
    out = rt.acquire(6, h, w)
    m = mask if mask is not None else guide
    launch_exact(rt, _kernel(rt, "gf_products", masked=mask is not None), w, h, guide.buffer, target.buffer,
                 m.buffer, out.buffer, i32(w), i32(h), _plane_base(guide, planes[0]), _plane_base(target, planes[1]),
                 _plane_base(m, planes[2] if mask is not None else 0))
    return out


def enqueue_coefficients(rt: Runtime, sums: DeviceImage, eps: float, weighted: bool) -> DeviceImage:
    """gf_coefficients: window sums (6 planes, the order of enqueue_products) -> planes a, b, or
    (``weighted``) a w, b w, w; same H x W. Halo 0."""
    out = rt.acquire(3 if weighted else 2, sums.height, sums.width)
    launch_exact(rt, _kernel(rt, "gf_coefficients", weighted=weighted), sums.width, sums.height, sums.buffer,
                 out.buffer, i32(sums.width), i32(sums.height), f32(eps))
    return out


def enqueue_apply(rt: Runtime, coef_sums: DeviceImage, guide: DeviceImage, offset: tuple[int, int],
                  count: float, weighted: bool, guide_plane: int = 0) -> DeviceImage:
    """gf_apply: q = (A x + B) / D over the coefficient sums' h x w, x = plane ``guide_plane`` of guide
    at (i + offset[0], j + offset[1]); D = ``count`` (plain) or W + 1e-4 (weighted). Halo 0."""
    h, w = coef_sums.height, coef_sums.width
    oy, ox = offset
    if oy < 0 or ox < 0 or oy + h > guide.height or ox + w > guide.width:
        raise ClispError(f"guide {guide.height} x {guide.width} does not hold {h} x {w} at {offset}")
    out = rt.acquire(1, h, w)
    base = int(_plane_base(guide, guide_plane)) + oy * guide.width + ox
    launch_exact(rt, _kernel(rt, "gf_apply", weighted=weighted), w, h, coef_sums.buffer, guide.buffer, out.buffer,
                 i32(w), i32(h), i32(base), i32(guide.width), f32(count))
    return out


def enqueue_centred_coefficients(rt: Runtime, guide: DeviceImage, target: DeviceImage, mask: DeviceImage | None,
                                 ry: int, rx: int, eps: float, weighted: bool,
                                 planes: tuple[int, int, int] = (0, 0, 0)) -> DeviceImage:
    """gf_row_moments then gf_col_coefficients: the coefficients of enqueue_coefficients (a, b or a w,
    b w, w) from statistics centred on each window's centre pixel (float32-safe variances), over the
    (H - 2ry) x (W - 2rx) window centres of H x W guide / target / mask planes. Halo ry, rx."""
    h, w = guide.height, guide.width
    for name, image in (("target", target), ("mask", mask)):
        if image is not None and (image.height, image.width) != (h, w):
            raise ClispError(f"device guided filter: {name} is {image.height} x {image.width}, guide {h} x {w}")
    m = mask if mask is not None else guide
    xb, yb = _plane_base(guide, planes[0]), _plane_base(target, planes[1])
    rw = w - 2 * rx
    rows = rt.acquire(6, h, rw)
    launch_exact(rt, _kernel(rt, "gf_row_moments", masked=mask is not None), rw, h, guide.buffer, target.buffer,
                 m.buffer, rows.buffer, i32(rx), i32(w), i32(rw), i32(h), xb, yb,
                 _plane_base(m, planes[2] if mask is not None else 0))
    out = rt.acquire(3 if weighted else 2, h - 2 * ry, rw)
    launch_exact(rt, _kernel(rt, "gf_col_coefficients", weighted=weighted), rw, h - 2 * ry, rows.buffer,
                 guide.buffer, target.buffer, out.buffer, i32(ry), i32(rw), i32(h), i32(h - 2 * ry), i32(xb + rx),
                 i32(yb + rx), i32(w), f32(eps))
    rt.release(rows)
    return out


def device_guided_filter(rt: Runtime, guide: DeviceImage, target: DeviceImage, mask: DeviceImage | None,
                         window: Window, eps: float = 1e-10, weighted: bool = False,
                         planes: tuple[int, int, int] = (0, 0, 0), centred: bool = True) -> DeviceImage:
    """bayer_ri.guided_filter(guide, target, mask, window, eps, weighted=weighted) on one padded window.

    guide, target, mask (None: every pixel; else 1.0 at the pixels of the statistics, 0.0 elsewhere):
    H x W float32 (plane ``planes[k]`` of each image); window ("box", ry, rx); eps in squared guide
    units (ARI: 8-bit, 1e-10). Returns a new 1 x (H - 4ry) x (W - 4rx) image, pixel (i, j) being the
    filter at input pixel (i + 2ry, j + 2rx): the halo is 2ry along y and 2rx along x. Enqueued only
    (in order on rt.queue); the temporaries go back to the pool.

    ``centred`` (default): window statistics centred on each window's centre pixel
    (enqueue_centred_coefficients, two kernels); False: the uncentred six-product sums (gf_products,
    box_x, box_y, gf_coefficients), whose float32 variances lose ~1e-7 E[x^2] to cancellation."""
    ry, rx = _radii(window)
    h, w = guide.height, guide.width
    if h - 4 * ry < 1 or w - 4 * rx < 1:
        raise ClispError(f"device guided filter: window {window!r} needs more than {h} x {w} pixels")
    if centred:
        coef = enqueue_centred_coefficients(rt, guide, target, mask, ry, rx, eps, weighted, planes)
    else:
        products = enqueue_products(rt, guide, target, mask, planes)
        sums = enqueue_box(rt, products, ry, rx, release_src=True)
        coef = enqueue_coefficients(rt, sums, eps, weighted)
        rt.release(sums)
    coef_sums = enqueue_box(rt, coef, ry, rx, release_src=True)
    count = float((2 * ry + 1) * (2 * rx + 1))
    q = enqueue_apply(rt, coef_sums, guide, (2 * ry, 2 * rx), count, weighted, planes[0])
    rt.release(coef_sums)
    return q
