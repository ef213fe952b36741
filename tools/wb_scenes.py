"""Scenes made in code for white balance ``auto`` (issue 42, item 1): the tuning set.

    import wb_scenes; scene = wb_scenes.make_scene("surface", seed=3)   # H x W x 3 linear sRGB

Nothing here reads a photograph: the estimate is tuned on these, and Kodak, McMaster and the
camera raws judge it (tools/bench_wb_auto.py). Kinds (KINDS), each drawn from a seed:

* ``leaves``    dead leaves (radii 3..80 px, r^-3) whose colours come from a palette of one
                *mood* (below; LEAVES_MOODS by seed, half natural), shaded by a 1/f lightness
                field and a smooth light gradient; every third seed with specular highlights;
* ``surface``   one coloured surface filling 60-95 % of the frame (wood, foliage, skin, brick,
                sky, sand, fabric of any hue), with grain, and a few objects on it; even seeds
                hold a near-white object (a cup, paper), every third seed specular highlights of
                the light (clipping); the espresso-cup-on-wood kind of photo;
* ``chart``     the ColorChecker's 24 patches on a wall of one mood's colour, shaded;
* ``landscape`` a sky gradient over ground texture (grass, soil, rock), sometimes with clouds;
* ``vivid``     clisp.sim.charts.dead_leaves: colours uniform in the sRGB cube (saturated).

A mood is a distribution of surface colours in CIELAB: ``natural`` (mostly low chroma, any hue),
``warm`` (browns, wood, skin), ``green`` (foliage), ``blue`` (sky, water), ``vivid`` (high chroma).
Scenes are linear sRGB under D65 (white 1); the light is multiplied in by the caller.
"""
from __future__ import annotations

import numpy as np

KINDS = ("leaves", "surface", "chart", "landscape", "vivid")
MOODS = ("natural", "warm", "green", "blue", "vivid")
LEAVES_MOODS = ("natural", "warm", "natural", "green", "natural", "blue", "natural", "vivid")
"""The mood of dead leaves of seed s: LEAVES_MOODS[s % 8] (half of them natural)."""
SIZE = (384, 512)
"""(height, width) of a scene, pixels."""

_LAB_WHITE = np.array([0.95047, 1.0, 1.08883])
_XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                         [-0.9692660, 1.8760108, 0.0415560],
                         [0.0556434, -0.2040259, 1.0572252]])


def lab_to_linear_srgb(lab: np.ndarray) -> np.ndarray:
    """CIELAB (D65) to linear sRGB, shape (..., 3); not clipped."""
    lab = np.asarray(lab, dtype=np.float64)
    fy = (lab[..., 0] + 16.0) / 116.0
    f = np.stack([fy + lab[..., 1] / 500.0, fy, fy - lab[..., 2] / 200.0], axis=-1)
    xyz = np.where(f > 6 / 29, f ** 3, 3 * (6 / 29) ** 2 * (f - 4 / 29)) * _LAB_WHITE
    return xyz @ _XYZ_TO_SRGB.T


def palette(rng: np.random.Generator, mood: str, n: int) -> np.ndarray:
    """``n`` surface colours of ``mood`` (module docstring), linear sRGB in gamut, shape (n, 3)."""
    lightness = rng.uniform(25.0, 90.0, n)
    if mood == "natural":
        chroma = rng.exponential(14.0, n)
        hue = rng.uniform(0.0, 360.0, n)
    elif mood == "warm":
        chroma = rng.uniform(12.0, 50.0, n)
        hue = rng.normal(65.0, 18.0, n)
        lightness = rng.uniform(20.0, 75.0, n)
    elif mood == "green":
        chroma = rng.uniform(10.0, 55.0, n)
        hue = rng.normal(125.0, 20.0, n)
        lightness = rng.uniform(20.0, 70.0, n)
    elif mood == "blue":
        chroma = rng.uniform(8.0, 45.0, n)
        hue = rng.normal(250.0, 20.0, n)
    elif mood == "vivid":
        chroma = rng.uniform(30.0, 90.0, n)
        hue = rng.uniform(0.0, 360.0, n)
    else:
        raise ValueError(f"unknown mood {mood!r}")
    out = np.empty((n, 3))
    for i in range(n):
        c = min(chroma[i], 100.0)
        while True:              # the chroma this hue and lightness allow in sRGB
            h = np.radians(hue[i])
            rgb = lab_to_linear_srgb(np.array([lightness[i], c * np.cos(h), c * np.sin(h)]))
            if np.all(rgb >= 0.002) and np.all(rgb <= 1.0) or c < 1.0:
                break
            c *= 0.9
        out[i] = np.clip(rgb, 0.002, 1.0)
    return out


def fractal(rng: np.random.Generator, shape: tuple[int, int], slope: float = 2.0,
            stretch: float = 1.0) -> np.ndarray:
    """1/f^(slope/2) noise, zero mean, unit standard deviation, shape ``shape``; ``stretch`` > 1
    elongates it along x (wood grain)."""
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.rfftfreq(shape[1])[None, :] * stretch
    f = np.sqrt(fy * fy + fx * fx)
    f[0, 0] = 1.0
    spectrum = (rng.normal(size=f.shape) + 1j * rng.normal(size=f.shape)) / f ** (slope / 2)
    spectrum[0, 0] = 0.0
    field = np.fft.irfft2(spectrum, s=shape)
    return field / field.std()


def shading(rng: np.random.Generator, shape: tuple[int, int], depth: float) -> np.ndarray:
    """A positive lightness field: a smooth gradient times 1/f noise, mean about 1."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] / max(shape)
    angle = rng.uniform(0, 2 * np.pi)
    gradient = 1.0 + rng.uniform(0.0, 0.6) * (np.cos(angle) * (xx - 0.5) + np.sin(angle) * (yy - 0.5))
    return np.clip(gradient * np.exp(depth * fractal(rng, shape, 2.6)), 0.05, None)


def _disc_mask(shape: tuple[int, int], cy: float, cx: float, ry: float, rx: float) -> np.ndarray:
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    return ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1.0


def _leaves(rng: np.random.Generator, shape: tuple[int, int], colours: np.ndarray) -> np.ndarray:
    out = np.zeros((*shape, 3))
    free = np.ones(shape, dtype=bool)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    for _ in range(4000):
        r = (3.0 ** -2 - rng.random() * (3.0 ** -2 - 80.0 ** -2)) ** -0.5
        cy, cx = rng.uniform(-r, shape[0] + r), rng.uniform(-r, shape[1] + r)
        y0, y1 = max(int(cy - r), 0), min(int(cy + r) + 1, shape[0])
        x0, x1 = max(int(cx - r), 0), min(int(cx + r) + 1, shape[1])
        if y0 >= y1 or x0 >= x1:
            continue
        m = ((yy[y0:y1, x0:x1] - cy) ** 2 + (xx[y0:y1, x0:x1] - cx) ** 2 <= r * r) & free[y0:y1, x0:x1]
        out[y0:y1, x0:x1][m] = colours[rng.integers(len(colours))]
        free[y0:y1, x0:x1][m] = False
        if not free.any():
            break
    out[free] = colours[0]
    return out


SURFACES = {"wood": (55.0, 30.0, 62.0, 6.0), "foliage": (45.0, 35.0, 125.0, 1.0), "skin": (65.0, 22.0, 55.0, 1.0),
            "brick": (45.0, 35.0, 40.0, 1.5), "sky": (70.0, 25.0, 245.0, 1.0), "sand": (75.0, 20.0, 80.0, 1.0),
            "fabric": (50.0, 40.0, None, 1.0)}
"""Dominant surfaces: (L*, C*, hue in degrees or None for any, grain stretch along x)."""


def _surface(rng: np.random.Generator, shape: tuple[int, int], white: bool) -> np.ndarray:
    name = list(SURFACES)[rng.integers(len(SURFACES))]
    lightness, chroma, hue, stretch = SURFACES[name]
    hue = rng.uniform(0, 360) if hue is None else hue + rng.normal(0, 8)
    base = lab_to_linear_srgb(np.array([lightness + rng.normal(0, 8), chroma * rng.uniform(0.6, 1.3) * np.cos(np.radians(hue)),
                                        chroma * rng.uniform(0.6, 1.3) * np.sin(np.radians(hue))]))
    base = np.clip(base, 0.003, 0.9)
    grain = np.exp(0.25 * fractal(rng, shape, 2.2, stretch))
    out = base * grain[..., None]
    colours = palette(rng, "natural", 8)
    for _ in range(rng.integers(0, 6)):
        ry, rx = rng.uniform(10, shape[0] / 4), rng.uniform(10, shape[1] / 4)
        m = _disc_mask(shape, rng.uniform(0, shape[0]), rng.uniform(0, shape[1]), ry, rx)
        out[m] = colours[rng.integers(len(colours))] * np.exp(0.1 * fractal(rng, shape))[m][:, None]
    if white:                                    # a near-white object: cup, plate, paper
        white = lab_to_linear_srgb(np.array([rng.uniform(80, 95), rng.normal(0, 2), rng.normal(0, 3)]))
        ry, rx = rng.uniform(20, shape[0] / 5), rng.uniform(20, shape[1] / 5)
        cy, cx = rng.uniform(ry, shape[0] - ry), rng.uniform(rx, shape[1] - rx)
        m = _disc_mask(shape, cy, cx, ry, rx)
        yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
        shade = np.clip(1.0 - 0.5 * ((xx - cx) / rx + 0.3 * (yy - cy) / ry), 0.3, 1.0)
        out[m] = np.clip(white, 0, 1) * shade[m][:, None]
    return out


def _chart(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    from clisp.sim.charts import colorchecker_linear
    patches = np.asarray(colorchecker_linear()).reshape(24, 3)
    wall = palette(rng, MOODS[rng.integers(4)], 1)[0]
    out = np.broadcast_to(wall, (*shape, 3)).copy() * np.exp(0.05 * fractal(rng, shape))[..., None]
    size = int(min(shape[0] / 4, shape[1] / 6) * rng.uniform(0.4, 0.9))
    y0 = rng.integers(0, shape[0] - 4 * size + 1)
    x0 = rng.integers(0, shape[1] - 6 * size + 1)
    gap = max(2, size // 6)
    for i, colour in enumerate(patches):
        r, c = divmod(i, 6)
        out[y0 + r * size + gap:y0 + (r + 1) * size - gap, x0 + c * size + gap:x0 + (c + 1) * size - gap] = colour
    return out


def _landscape(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    h, w = shape
    horizon = int(h * rng.uniform(0.2, 0.6))
    yy = np.arange(h)[:, None] / h
    sky_top = lab_to_linear_srgb(np.array([rng.uniform(55, 75), -5 + rng.normal(0, 3), -rng.uniform(15, 40)]))
    sky_low = lab_to_linear_srgb(np.array([rng.uniform(80, 92), rng.normal(0, 2), -rng.uniform(0, 12)]))
    t = np.clip(yy / max(horizon / h, 1e-3), 0, 1)[..., None]
    out = np.clip((1 - t) * sky_top + t * sky_low, 0.002, 1.0) * np.ones((h, w, 1))
    if rng.random() < 0.5:                       # clouds: white to grey
        cloud = np.clip(fractal(rng, shape, 3.0) - 0.5, 0, None)
        cloud = (cloud / max(cloud.max(), 1e-9))[..., None]
        grey = rng.uniform(0.6, 0.95)
        out = out * (1 - cloud) + grey * cloud
    ground = palette(rng, ["green", "warm", "natural"][rng.integers(3)], 6)
    mix = fractal(rng, shape, 2.4)
    idx = np.clip(((mix - mix.min()) / (np.ptp(mix) + 1e-9) * len(ground)).astype(int), 0, len(ground) - 1)
    land = ground[idx] * np.exp(0.3 * fractal(rng, shape, 1.8))[..., None]
    out[horizon:] = land[horizon:]
    return out


def make_scene(kind: str, seed: int, shape: tuple[int, int] = SIZE) -> np.ndarray:
    """A scene of ``kind`` (KINDS) drawn from ``seed``: H x W x 3 linear sRGB under D65, its
    bright end (99.5th percentile of the largest channel, speculars apart) at 0.55..0.95."""
    rng = np.random.default_rng([KINDS.index(kind), seed])
    if kind == "leaves":
        mood = LEAVES_MOODS[seed % len(LEAVES_MOODS)]
        out = _leaves(rng, shape, palette(rng, mood, 40)) * shading(rng, shape, 0.25)[..., None]
    elif kind == "surface":
        out = _surface(rng, shape, white=seed % 2 == 0) * shading(rng, shape, 0.15)[..., None]
    elif kind == "chart":
        out = _chart(rng, shape) * shading(rng, shape, 0.1)[..., None]
    elif kind == "landscape":
        out = _landscape(rng, shape)
    elif kind == "vivid":
        from clisp.sim.charts import dead_leaves
        out = dead_leaves(max(shape), seed=int(rng.integers(1 << 30)), ss=1)[:shape[0], :shape[1]]
    else:
        raise ValueError(f"unknown kind {kind!r}; expected one of {', '.join(KINDS)}")
    out = out * (rng.uniform(0.55, 0.95) / max(float(np.percentile(out.max(axis=-1), 99.5)), 1e-6))
    if kind in ("surface", "leaves") and seed % 3 == 0:      # specular highlights of the light
        for _ in range(rng.integers(1, 4)):
            cy, cx, r = rng.uniform(0, shape[0]), rng.uniform(0, shape[1]), rng.uniform(2, 8)
            yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
            spot = rng.uniform(0.8, 3.0) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r))
            out = out + spot[..., None]
    return np.clip(out, 0.0, None)
