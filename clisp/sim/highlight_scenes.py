"""Scenes made in code where clipped highlights meet noise and colour (issue 43), linear sRGB.

The simulator puts sRGB white at full scale (clisp.sim.simulate: k_exp), so a value of 1.0 in the
brightest camera channel is exactly the clip level and values past 1 are past it:

* :func:`specular_ring`: glossy spheres of saturated colour (red, green, blue) on a dark ground,
  each with a white specular highlight up to ``peak`` times white. Around the clipped core the
  highlight is white added to the surface colour (pink on red): the ring where a highlight stage
  that paints its rim one colour (the surface's, or neutral) shows a grey or coloured ring.
* :func:`white_shirt`: a white shirt exposed to the right: folds whose crests reach exactly full
  scale (1.0) and whose valleys fall to 0.85, a fine weave, a placket seam and buttons. Nothing in
  it is past the clip; at any gain the noise clips part of the crests' samples.
* :func:`light_beside`: a lamp (a soft-edged disc at ``peak`` times white on a dim wall), the
  white shirt to its left and a red glossy sphere to its right: a light truly past the clip beside
  both of the above.

Each returns an n x n x 3 float64 array; the values are deterministic (no random numbers).
:func:`specular_rim` marks where a clipped highlight's core meets the surface around it, where
issue 43 bounds every reconstructed pixel's error (tests/modules/test_highlights.py,
tools/bench_highlights.py).
"""
from __future__ import annotations

import numpy as np

from ..scene.noise import CLIP_FRACTION
from .simulate import inverse_isp_matrix

SPHERES = ((0.78, 0.05, 0.04), (0.05, 0.52, 0.07), (0.04, 0.07, 0.72))
"""Diffuse colours of :func:`specular_ring`'s spheres: saturated red, green and blue."""


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[:n, :n]
    return (yy + 0.5) / n, (xx + 0.5) / n


def glossy_sphere(img: np.ndarray, yy: np.ndarray, xx: np.ndarray, centre: tuple[float, float], radius: float,
                  colour: tuple[float, float, float], peak: float, shininess: float = 50.0) -> np.ndarray:
    """``img`` with a sphere painted on it: Lambert diffuse in ``colour`` (lit from the upper left,
    plus 0.03 of ambient) and a white Blinn-Phong highlight of ``peak`` times white at its top."""
    light = np.array([-0.45, -0.55, 0.70])
    light /= np.linalg.norm(light)
    half = light + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    dx, dy = (xx - centre[1]) / radius, (yy - centre[0]) / radius
    inside = dx ** 2 + dy ** 2 < 1.0
    nz = np.sqrt(np.clip(1.0 - dx ** 2 - dy ** 2, 0.0, 1.0))
    normal = np.stack([dx, dy, nz], axis=-1)
    diffuse = np.clip(normal @ light, 0.0, 1.0)[..., None] * np.asarray(colour) + 0.03 * np.asarray(colour) / max(colour)
    spec = peak * np.clip(normal @ half, 0.0, 1.0)[..., None] ** shininess
    return np.where(inside[..., None], diffuse + spec, img)


def specular_ring(n: int = 192, peak: float = 2.5) -> np.ndarray:
    """Three glossy spheres (red, green, blue: SPHERES) with white highlights up to ``peak``."""
    yy, xx = _grid(n)
    img = np.stack([0.05 + 0.03 * yy, 0.05 + 0.03 * yy, 0.06 + 0.03 * yy], axis=-1)
    for (cy, cx), colour in zip(((0.3, 0.28), (0.3, 0.74), (0.74, 0.5)), SPHERES):
        img = glossy_sphere(img, yy, xx, (cy, cx), 0.22, colour, peak)
    return img


def white_shirt(n: int = 192) -> np.ndarray:
    """A white shirt exposed to the right (every value at most 1.0, the crests of its folds at 1.0)."""
    yy, xx = _grid(n)
    fold = 0.5 + 0.5 * np.cos(2 * np.pi * (2.3 * xx + 0.6 * np.sin(2 * np.pi * 1.1 * yy)))
    level = 1.0 - 0.15 * fold ** 2
    weave = 1.0 - 0.02 * (np.sin(np.pi * n / 3 * xx) * np.sin(np.pi * n / 3 * yy)) ** 2
    img = np.repeat((level * weave)[..., None], 3, axis=-1)
    seam = np.abs(xx - 0.5) < 1.5 / n
    img[seam] *= 0.88
    for cy in (0.2, 0.45, 0.7, 0.95):
        button = np.hypot(yy - cy, xx - 0.53) < 0.025
        img[button] = (0.45, 0.42, 0.38)
    collar = yy < 0.06
    img[collar] *= 0.55
    return np.minimum(img, 1.0)


def light_beside(n: int = 192, peak: float = 3.0) -> np.ndarray:
    """The white shirt (left third), a lamp of ``peak`` times white on a dim wall (middle) and a red
    glossy sphere with its highlight (right third)."""
    yy, xx = _grid(n)
    img = np.stack([0.14 + 0.0 * yy, 0.12 + 0.0 * yy, 0.10 + 0.0 * yy], axis=-1)
    shirt = white_shirt(n)
    left = xx < 0.34
    img[left] = shirt[left]
    lamp = np.clip((0.1 - np.hypot(yy - 0.5, xx - 0.5)) / 0.025, 0.0, 1.0)[..., None]
    img = img * (1 - lamp) + peak * lamp
    return glossy_sphere(img, yy, xx, (0.5, 0.82), 0.14, SPHERES[0], 2.5)


def highlight_scenes(n: int = 192) -> dict[str, np.ndarray]:
    """The three scenes by name (n x n each)."""
    return {"specular ring": specular_ring(n), "white shirt": white_shirt(n), "light beside": light_beside(n)}


RIM_REACH = 6
"""The specular rim reaches this far (px, Chebyshev) from the clipped region."""


def specular_rim(truth: np.ndarray, cfa: str) -> np.ndarray:
    """H x W bool: issue 43's "specular rim": the pixels within RIM_REACH of the clipped region
    (truth at or past CLIP_FRACTION in some raw channel) where at most one raw channel of the truth
    is past it, so that two recorded channels say the colour: where a highlight's clipped core meets
    the surface around it. (Where two channels clip, one record says only a brightness; where all
    three do, not even that.)"""
    a, _ = inverse_isp_matrix(cfa)
    raw = truth @ a.T
    clipped = raw.max(-1) >= CLIP_FRACTION
    if not clipped.any():
        return np.zeros(truth.shape[:2], dtype=bool)
    grown = _grow(clipped, RIM_REACH)
    return grown & ((raw >= CLIP_FRACTION).sum(-1) <= 1)


def _grow(mask: np.ndarray, k: int) -> np.ndarray:
    """``mask`` (H x W bool) grown by k px (Chebyshev)."""
    padded = np.pad(mask, k)
    h, w = mask.shape
    out = np.zeros_like(mask)
    for dy in range(2 * k + 1):
        for dx in range(2 * k + 1):
            out |= padded[dy:dy + h, dx:dx + w]
    return out
