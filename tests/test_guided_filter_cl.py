"""The RI / ARI masked guided filter on the device (clisp.modules.common.guided_ri, clisp/modules/common/guided_ri.cl) against
its float64 NumPy reference bayer_ri.guided_filter.

The device filter reads one padded H x W window and returns its (H - 4ry) x (W - 4rx) interior; the
reference, computed on a larger array (mirrored borders far away), is cropped to the same pixels.
Data in ARI's units (8-bit values, 0..255), masks the Bayer site masks (bayer_ri.Sites).

Tolerance (float32 kernels, float64 reference on the same float32-rounded inputs), relative to 255:

    |opencl - reference| <= TOL_PLAIN * 255 (plain), TOL_WEIGHTED * 255 (ARI's 1 / RMSE weights)

MEASURED holds the worst cases over CASES (PoCL CPU). The weighted form is looser: its weights
1 / max(RMSE, 1e-3) amplify the rounding of mse = a^2 var_x - 2 a cov + var_y where fits are good.
The default device path centres the statistics on each window's centre pixel; the uncentred path
(six product planes, centred=False) loses ~1e-7 E[x^2] of every variance to cancellation (~4e-3 at
255) and gets its own, looser bounds (UNCENTRED_*), measured on the same data.
Ill-posed windows are left out: a 5 x 3 window holds as few as 2 R sites, where a two-point fit is
exact (mse = 0: the weight is set by rounding, 1 / 1e-3 in the reference, ~30 in float32) or nearly
singular (two nearly equal guide values; eps = 1e-10 does not regularise): errors up to 45 x 255.
"""
from __future__ import annotations

import numpy as np
import pytest

from clisp.modules.demosaic_ari import reference as br
from clisp.modules.common.guided_ri import device_guided_filter

SCALE = 255.0
TOL_PLAIN = 2e-6
TOL_WEIGHTED = 5e-5
UNCENTRED_PLAIN = 1e-3
UNCENTRED_WEIGHTED = 6e-3
MEASURED = {("random", "plain"): 5.6e-7, ("random", "weighted"): 1.0e-6,
            ("structured", "plain"): 2.9e-7, ("structured", "weighted"): 1.7e-5,
            ("uncentred", "random", "plain"): 1.6e-5, ("uncentred", "random", "weighted"): 4.4e-5,
            ("uncentred", "structured", "plain"): 2.8e-4, ("uncentred", "structured", "weighted"): 2.2e-3}
"""Worst |opencl - reference| / 255 over CASES, PoCL CPU (the structured guide's noise, sigma 2 on
values ~100-250, is where uncentred sums cancel: 2.2e-3 x 255 = 0.56 8-bit levels)."""
SHAPE = (48, 80)            # reference array; the device window is a crop of it
CROP = (3, 5, 44, 73)       # device window rows 3..44, columns 5..73 (odd offsets: another CFA phase)
WINDOWS = [("box", 0, 5), ("box", 3, 3), ("box", 2, 1)]


def random_pair(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 255, SHAPE), rng.uniform(0, 255, SHAPE)


def structured_pair(seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A smooth ramp with a few steps and noise (guide), and a target correlated with it locally
    (slope and offset varying across the image): good fits, where the weighted form is hardest."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(np.float64)
    guide = 60 + 1.2 * xx + 0.8 * yy + 70 * (xx + 0.5 * yy > 50) - 50 * ((xx - 30) ** 2 + (yy - 24) ** 2 < 80)
    guide += rng.normal(0, 2.0, SHAPE)
    target = (0.6 + 0.004 * xx) * guide + 20 + 0.3 * yy + rng.normal(0, 1.0, SHAPE)
    return np.clip(guide, 0, 255), np.clip(target, 0, 255)


def masks() -> dict[str, np.ndarray | None]:
    sites = br.Sites(SHAPE)
    return {"all": None, "g": sites.g, "r": sites.r, "c": sites.c,
            "rline": sites.lines("h")[0][0], "bcol": sites.lines("v")[1][0]}   # ARI's G-step line masks


def run_device(rt, guide, target, mask, window, weighted, crop=CROP, centred=True):
    y0, x0, y1, x1 = crop

    def up(a):
        return rt.upload(np.ascontiguousarray(a[y0:y1, x0:x1], dtype=np.float32))
    q = device_guided_filter(rt, up(guide), up(target), None if mask is None else up(mask), window,
                             eps=1e-10, weighted=weighted, centred=centred)
    return rt.download(q)


def reference(guide, target, mask, window, weighted, crop=CROP):
    """bayer_ri.guided_filter on the whole array (float32-rounded inputs), cropped to the device output."""
    g32, t32 = (np.float32(a).astype(np.float64) for a in (guide, target))
    ref = br.guided_filter(g32, t32, mask, window, eps=1e-10, weighted=weighted)
    y0, x0, y1, x1 = crop
    _, ry, rx = window
    return ref[y0 + 2 * ry:y1 - 2 * ry, x0 + 2 * rx:x1 - 2 * rx]


def scaled_error(out, ref) -> float:
    assert out.shape == ref.shape
    assert np.all(np.isfinite(out))
    return float(np.abs(out.astype(np.float64) - ref).max() / SCALE)


CASES = [(w, m) for w in WINDOWS for m in ("all", "g", "r", "c", "rline", "bcol")
         if not (w == ("box", 2, 1) and m == "r")]      # 5 x 3 windows hold only 2 R sites: ill-conditioned


@pytest.mark.parametrize("centred", [True, False], ids=["centred", "uncentred"])
@pytest.mark.parametrize("weighted", [False, True], ids=["plain", "weighted"])
@pytest.mark.parametrize("data", ["random", "structured"])
def test_matches_reference(rt, data, weighted, centred):
    guide, target = random_pair() if data == "random" else structured_pair()
    tol = ((TOL_WEIGHTED if weighted else TOL_PLAIN) if centred
           else (UNCENTRED_WEIGHTED if weighted else UNCENTRED_PLAIN))
    worst = 0.0
    for window, m in CASES:
        mask = masks()[m]
        err = scaled_error(run_device(rt, guide, target, mask, window, weighted, centred=centred),
                           reference(guide, target, mask, window, weighted))
        worst = max(worst, err)
        assert err <= tol, f"{data} {window} mask {m}: error {err:.3g} x 255 > {tol:g}"
    print(f"{data} {'weighted' if weighted else 'plain'} {'centred' if centred else 'uncentred'}: worst {worst:.3g} x 255")


def test_wrong_window_or_mask_fails(rt):
    """The comparison discriminates: a transposed window, another mask, or no mask is far off."""
    guide, target = random_pair()
    sites = br.Sites(SHAPE)
    out = run_device(rt, guide, target, sites.g, ("box", 2, 1), weighted=True)
    assert scaled_error(out, reference(guide, target, sites.g, ("box", 2, 1), True)) <= TOL_WEIGHTED
    ref_t = reference(guide, target, sites.g, ("box", 1, 2), True)   # transposed: compare the common pixels
    assert scaled_error(out[:, 2:-2], ref_t[2:-2, :]) > 100 * TOL_WEIGHTED
    for other in (sites.c, None):
        assert scaled_error(out, reference(guide, target, other, ("box", 2, 1), True)) > 100 * TOL_WEIGHTED
    sparse = np.where(sites.r, target, 0.0)     # RI: target known at the R sites only
    out = run_device(rt, guide, sparse, sites.r, ("box", 3, 3), weighted=False)
    assert scaled_error(out, reference(guide, sparse, sites.r, ("box", 3, 3), False)) <= TOL_PLAIN
    assert scaled_error(out, reference(guide, sparse, sites.b, ("box", 3, 3), False)) > 100 * TOL_PLAIN
    assert scaled_error(out, reference(guide, sparse, sites.r, ("box", 3, 2), False)[:, 2:-2]) > 100 * TOL_PLAIN


def test_output_geometry(rt):
    """Output (H - 4ry) x (W - 4rx); a window too small for the halo is refused."""
    from clisp.errors import ClispError
    guide, target = random_pair()
    out = run_device(rt, guide, target, None, ("box", 2, 1), False, crop=(0, 0, 9, 7))
    assert out.shape == (1, 3)
    with pytest.raises(ClispError):
        run_device(rt, guide, target, None, ("box", 2, 1), False, crop=(0, 0, 8, 7))
