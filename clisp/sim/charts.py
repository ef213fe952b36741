"""Built-in test scenes generated in code (docs/model.md section 5).

Every scene is an H x W x 3 float64 array of LINEAR sRGB (D65), white = 1.0, values in [0, 1],
with H and W multiples of 4. Boxes are ``(y0, y1, x0, x1)`` half-open pixel ranges.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .colorimetry import srgb_decode

Box = tuple[int, int, int, int]
"""(y0, y1, x0, x1): rows y0..y1-1, columns x0..x1-1."""

COLORCHECKER_NAME = "ColorChecker24 - After November 2014"
BACKGROUND = 0.18
"""Linear mid-grey used behind the targets [decision] (sRGB-encoded ~0.46)."""
NEUTRAL_INDICES = (23, 22, 21, 20, 19, 18)
"""ColorChecker patch indices of the neutrals, darkest -> brightest (black 2 ... white 9.5)."""
SPEC_NEUTRAL_LUMINANCE = (0.0315, 0.0882, 0.1906, 0.3649, 0.5900, 0.8807)
"""Linear values of the six neutrals, black 2 .. white 9.5 (docs/model.md section 5; = the patches'
CIE Y; per-channel RGB differs slightly)."""


def _colour():
    """Import colour-science lazily (about 0.6 s) and without its matplotlib warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour            # deferred: colour-science costs about 0.6 s of start-up
    return colour


@lru_cache(maxsize=1)
def _colorchecker_linear_cached() -> np.ndarray:
    colour = _colour()
    chart = colour.CCS_COLOURCHECKERS[COLORCHECKER_NAME]
    xyY = np.array(list(chart.data.values()), dtype=np.float64)
    rgb = colour.XYZ_to_RGB(colour.xyY_to_XYZ(xyY), colour.RGB_COLOURSPACES["sRGB"],
                            illuminant=chart.illuminant, chromatic_adaptation_transform="CAT02")
    rgb = np.clip(rgb, 0.0, 1.0)
    rgb.setflags(write=False)
    return rgb


def colorchecker_linear() -> np.ndarray:
    """(24, 3) linear sRGB of the ColorChecker patches (reading order), CAT02 to D65, clipped to [0, 1]."""
    return _colorchecker_linear_cached().copy()


def colorchecker(patch: int = 64, gap: int = 16, border: int = 16,
                 background: float = BACKGROUND) -> tuple[np.ndarray, list[Box]]:
    """ColorChecker 24 (4 rows x 6 columns) on a uniform grey background.

    Returns (image, rois): image (4*patch+3*gap+2*border) x (6*patch+5*gap+2*border) x 3 linear sRGB;
    rois = 24 patch boxes in reading order (row-major, 'dark skin' first, 'black 2 (5)' last).
    """
    h = 4 * patch + 3 * gap + 2 * border
    w = 6 * patch + 5 * gap + 2 * border
    image = np.full((h, w, 3), background, dtype=np.float64)
    colours = colorchecker_linear()
    rois: list[Box] = []
    for i in range(24):
        row, col = divmod(i, 6)
        y0 = border + row * (patch + gap)
        x0 = border + col * (patch + gap)
        image[y0:y0 + patch, x0:x0 + patch] = colours[i]
        rois.append((y0, y0 + patch, x0, x0 + patch))
    return image, rois


def central_box(box: Box, central: int = 32) -> Box:
    """The central ``central`` x ``central`` box of ``box``."""
    y0, y1, x0, x1 = box
    cy, cx = y0 + (y1 - y0 - central) // 2, x0 + (x1 - x0 - central) // 2
    return (cy, cy + central, cx, cx + central)


def gray_panel_rois(rois: list[Box], central: int = 32) -> list[Box]:
    """Central ROIs of the six neutral patches, ordered panel 1..6 = darkest -> brightest (docs/model.md section 5)."""
    return [central_box(rois[i], central) for i in NEUTRAL_INDICES]


def _supersample_grid(size: int, ss: int) -> tuple[np.ndarray, np.ndarray]:
    """Sample coordinates (y, x) in pixel units of a size x size image, ss x ss samples per pixel.

    Returned arrays have shape (size*ss, size*ss); pixel (0, 0) covers [0, 1) x [0, 1).
    """
    t = (np.arange(size * ss, dtype=np.float64) + 0.5) / ss
    return np.meshgrid(t, t, indexing="ij")


def _downsample(a: np.ndarray, ss: int) -> np.ndarray:
    """Box-average an (H*ss, W*ss, ...) array to (H, W, ...)."""
    h, w = a.shape[0] // ss, a.shape[1] // ss
    return a.reshape(h, ss, w, ss, *a.shape[2:]).mean(axis=(1, 3))


def _gray(plane: np.ndarray) -> np.ndarray:
    """H x W -> H x W x 3 neutral (R = G = B) float64."""
    return np.repeat(plane[:, :, None].astype(np.float64), 3, axis=2)


def zone_plate(size: int = 256, lo: float = 0.1, hi: float = 0.9, encoding: str = "srgb") -> np.ndarray:
    """Neutral circular zone plate, size x size x 3 linear sRGB.

    The sRGB-ENCODED value is (lo+hi)/2 + (hi-lo)/2 * cos(k r^2), r in px from the centre, with
    k = pi / (2 R), R = size/2, so the local frequency k r / pi cycles/px reaches Nyquist (0.5) at the
    edge of the inscribed disc; outside the disc the encoded value is (lo+hi)/2. Decoded to linear.
    ``encoding`` "linear": the same cosine in LINEAR values (a sinusoidal reflectance; the decoded
    sRGB cosine is far from sinusoidal, with strong harmonics up to 2-5x the local frequency).
    """
    if encoding not in ("srgb", "linear"):
        raise ValueError(f"zone plate encoding {encoding!r}: expected 'srgb' or 'linear'")
    c = size / 2.0
    y, x = np.mgrid[0:size, 0:size].astype(np.float64) + 0.5 - c
    r2 = x * x + y * y
    k = np.pi / (2.0 * c)
    mid, amp = (lo + hi) / 2.0, (hi - lo) / 2.0
    encoded = np.where(r2 <= c * c, mid + amp * np.cos(k * r2), mid)
    return _gray(srgb_decode(encoded) if encoding == "srgb" else encoded)


def siemens_star(size: int = 256, spokes: int = 36, lo: float = 0.05, hi: float = 0.75,
                 background: float = BACKGROUND, ss: int = 4) -> np.ndarray:
    """Neutral Siemens star, size x size x 3 linear sRGB.

    ``spokes`` dark/bright sector pairs (linear levels lo / hi) fill the inscribed disc; outside it the
    linear ``background``. Anti-aliased by ss x ss supersampling.
    """
    y, x = _supersample_grid(size, ss)
    c = size / 2.0
    y, x = y - c, x - c
    star = np.where(np.cos(spokes * np.arctan2(y, x)) >= 0.0, hi, lo)
    plane = np.where(x * x + y * y <= c * c, star, background)
    return _gray(_downsample(plane, ss))


def _disc_radii(rng: np.random.Generator, n: int, rmin: float, rmax: float) -> np.ndarray:
    """n radii with density ~ r^-3 on [rmin, rmax] (inverse-CDF sampling)."""
    a, b = rmin ** -2.0, rmax ** -2.0
    return (a - rng.random(n) * (a - b)) ** -0.5


def dead_leaves(size: int = 256, seed: int = 0, rmin: float = 2.0, rmax: float = 64.0,
                ss: int = 4, max_discs: int = 200_000, levels: tuple[float, float] = (0.05, 0.95)) -> np.ndarray:
    """Colour dead-leaves pattern, size x size x 3 linear sRGB, deterministic for ``seed``.

    Opaque discs (radius density ~ r^-3 on [rmin, rmax] px, centres uniform over the image grown by
    rmax, colours uniform in sRGB-encoded ``levels``^3, then decoded) are stacked front to back
    until every sample is covered. Anti-aliased by ss x ss supersampling.
    """
    rng = np.random.default_rng(seed)
    n_ss = size * ss
    out = np.zeros((n_ss, n_ss, 3))
    free = np.ones((n_ss, n_ss), dtype=bool)
    left = free.size
    t = (np.arange(n_ss, dtype=np.float64) + 0.5) / ss
    batch = 1024
    drawn = 0
    while left > 0 and drawn < max_discs:
        radii = _disc_radii(rng, batch, rmin, rmax)
        centres = rng.uniform(-rmax, size + rmax, size=(batch, 2))
        colours = srgb_decode(rng.uniform(levels[0], levels[1], size=(batch, 3)))
        for r, (cy, cx), col in zip(radii, centres, colours):
            left -= _paint_disc(out, free, t, cy, cx, r, col, ss)
            if left == 0:
                break
        drawn += batch
    if left > 0:
        out[free] = BACKGROUND
    return _downsample(out, ss)


def textured_leaves(size: int = 256, seed: int = 0, contrast: float = 0.35, beta: float = 2.0,
                    rmin: float = 0.4, rmax: float = 32.0) -> np.ndarray:
    """Dead leaves (colours over the whole sRGB-encoded range 0.05..1) whose surfaces carry shading
    and texture: each channel times exp(contrast n), n a Gaussian 1/f^(beta/2)-amplitude field (power
    ~ f^-beta: smooth gradients and fine grain together, as natural surfaces have) with unit standard
    deviation, one field for all channels. Clipped to [0, 1]; size x size x 3 linear sRGB.

    Where a flat disc puts a pixel's same-channel neighbours at its own level, a textured surface
    puts some above it (a gradient, a ridge): what a defect search meets in photos.

    >>> textured_leaves(32, seed=1).shape
    (32, 32, 3)
    """
    base = dead_leaves(size, seed=seed, rmin=rmin, rmax=rmax, levels=(0.05, 1.0))
    rng = np.random.default_rng(seed + 10_000)
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    f = np.hypot(fy, fx)
    f[0, 0] = 1.0
    spectrum = (rng.standard_normal(f.shape) + 1j * rng.standard_normal(f.shape)) * f ** (-beta / 2)
    spectrum[0, 0] = 0.0
    n = np.fft.irfft2(spectrum, s=(size, size))
    n /= n.std()
    return np.clip(base * np.exp(contrast * n)[..., None], 0.0, 1.0)


def _paint_disc(out: np.ndarray, free: np.ndarray, t: np.ndarray, cy: float, cx: float,
                r: float, colour: np.ndarray, ss: int) -> int:
    """Paint ``colour`` on the still-free samples inside the disc; return how many were painted."""
    n = free.shape[0]
    y0, y1 = max(int((cy - r) * ss), 0), min(int((cy + r) * ss) + 1, n)
    x0, x1 = max(int((cx - r) * ss), 0), min(int((cx + r) * ss) + 1, n)
    if y0 >= y1 or x0 >= x1:
        return 0
    dy = (t[y0:y1] - cy)[:, None]
    dx = (t[x0:x1] - cx)[None, :]
    new = (dy * dy + dx * dx <= r * r) & free[y0:y1, x0:x1]
    count = int(np.count_nonzero(new))
    if count:
        out[y0:y1, x0:x1][new] = colour
        free[y0:y1, x0:x1][new] = False
    return count


@dataclass
class Chart:
    """Composite demo scene: ``image`` H x W x 3 linear sRGB; boxes in composite pixel coordinates.

    regions: 'colorchecker' (the 4x6 patch block, without its border), 'zone_plate', 'siemens_star',
    'dead_leaves'. gray_rois: the six central 32x32 neutral ROIs, panel 1 (black) .. 6 (white).
    patch_rois: the 24 ColorChecker patch boxes in reading order.
    """
    image: np.ndarray
    regions: dict[str, Box]
    gray_rois: list[Box]
    patch_rois: list[Box] = field(default_factory=list)


DEMO_TARGET = 256
DEMO_GAP = 16


def demo_chart(seed: int = 0) -> Chart:
    """ColorChecker (64 px patches, 16 px gaps) centred on top; zone plate, Siemens star and dead
    leaves (256 x 256 each) in a row below; 16 px grey margins everywhere. Size 608 x 832 x 3.
    """
    g, s = DEMO_GAP, DEMO_TARGET
    cc, cc_rois = colorchecker(patch=64, gap=16, border=0)
    width = 3 * s + 4 * g
    height = g + cc.shape[0] + g + s + g
    image = np.full((height, width, 3), BACKGROUND)
    cy0, cx0 = g, (width - cc.shape[1]) // 2 // 4 * 4
    image[cy0:cy0 + cc.shape[0], cx0:cx0 + cc.shape[1]] = cc
    rois = [(y0 + cy0, y1 + cy0, x0 + cx0, x1 + cx0) for (y0, y1, x0, x1) in cc_rois]
    regions: dict[str, Box] = {"colorchecker": (cy0, cy0 + cc.shape[0], cx0, cx0 + cc.shape[1])}
    ty0 = cy0 + cc.shape[0] + g
    targets = {"zone_plate": zone_plate(s), "siemens_star": siemens_star(s),
               "dead_leaves": dead_leaves(s, seed=seed)}
    for i, (name, target) in enumerate(targets.items()):
        tx0 = g + i * (s + g)
        image[ty0:ty0 + s, tx0:tx0 + s] = target
        regions[name] = (ty0, ty0 + s, tx0, tx0 + s)
    return Chart(image=image, regions=regions, gray_rois=gray_panel_rois(rois), patch_rois=rois)
