"""Spectral scenes: raws simulated from reflectance spectra, not from sRGB (docs/model.md sections 2 and 5).

A spectral ColorChecker under D65 is seen by a camera with spectral sensitivities s_c:
``r_c = sum_lambda R(lambda) E(lambda) (lambda / 555) s_c(lambda)`` (photon counting), normalised so
the brightest channel of a perfect white is 1. LMS = Stockman & Sharpe 2-degree cone fundamentals
(energy-based, hence the lambda factor); Bayer = the Nikon D100 quantum efficiencies (``D100_QE``,
from ISETCam's sensor data, per photon), the same way. Ground truth is the scene's true colour:
CIE 1931 XYZ under D65 (Y of a perfect white = 1) in linear sRGB.

Because a chart is flat patches and every colour step is linear per pixel, the scene is carried as
an image of camera responses; the optics blur it exactly as they would blur the raw channels.
The camera's colour matrix is fitted, not assumed (eq. (1) is not the matrix of these cones):
white-preserving least squares from white-balanced responses to true sRGB over the 24 patches.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from .charts import BACKGROUND, central_box, colorchecker
from .colorimetry import XYZ_TO_SRGB
from .noise import NoiseModel, check_gain
from .optics import apply_optics
from .simulate import SimResult, _check_seed, _metadata, _optics_kernel, optics_and_mosaic, resolve_cfa
from ..errors import ClispError
from ..io.rawimage import RawImage
from ..metrics import linear_srgb_to_lab

WAVELENGTHS = np.arange(400, 701, 10)
"""Integration grid in nm (the D100 data are given at 400..700 nm, step 10)."""

D100_QE = np.array([
    [.013, .018, .116], [.011, .023, .229], [.009, .025, .307], [.005, .038, .373], [.007, .057, .483],
    [.005, .072, .600], [.004, .121, .697], [.012, .242, .775], [.012, .358, .752], [.013, .425, .605],
    [.020, .537, .414], [.021, .736, .242], [.057, .905, .097], [.080, .988, .045], [.040, .989, .025],
    [.030, .909, .010], [.011, .823, .009], [.065, .685, .006], [.403, .508, .004], [.714, .313, .003],
    [.645, .149, .000], [.531, .048, .001], [.424, .016, .002], [.293, .010, .000], [.215, .000, .000],
    [.142, .004, .000], [.093, .001, .000], [.062, .000, .000], [.033, .006, .000], [.026, .000, .000],
    [.013, .003, .000]])
"""Nikon D100 relative quantum efficiency (per photon), R, G, B at WAVELENGTHS (ISETCam's D100 data)."""

SPECTRAL_KINDS = ("lms", "bayer")
REFLECTANCE_SOURCES = ("colour", "isetcam")


def _colour():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour            # deferred: colour-science costs about 0.6 s of start-up
    return colour


def _resample(sd_like, wavelengths: np.ndarray = WAVELENGTHS) -> np.ndarray:
    """Values of a colour-science spectral distribution (or multi-SD) at ``wavelengths``."""
    colour = _colour()
    shape = colour.SpectralShape(float(wavelengths[0]), float(wavelengths[-1]), float(wavelengths[1] - wavelengths[0]))
    return np.asarray(sd_like.copy().align(shape).values)


@lru_cache(maxsize=None)
def sensitivities(kind: str) -> np.ndarray:
    """Camera spectral sensitivities at WAVELENGTHS, shape (n_lambda, 3), per photon.

    'lms': Stockman & Sharpe 2-degree cones (energy-based) times lambda/555, the photon-counting
    form; 'bayer': the D100 quantum efficiencies (already per photon).
    """
    if kind == "lms":
        cones = _resample(_colour().MSDS_CMFS["Stockman & Sharpe 2 Degree Cone Fundamentals"])
        return cones * (WAVELENGTHS / 555.0)[:, None]
    if kind == "bayer":
        return D100_QE.copy()
    raise ClispError(f"no spectral sensitivities for CFA kind {kind!r}; expected one of {', '.join(SPECTRAL_KINDS)}")


@lru_cache(maxsize=None)
def illuminant_d65() -> np.ndarray:
    """CIE D65 relative spectral power at WAVELENGTHS, shape (n_lambda,)."""
    return _resample(_colour().SDS_ILLUMINANTS["D65"])


def reflectances(source: str = "colour", data: str | Path | None = None) -> np.ndarray:
    """The 24 ColorChecker reflectances at WAVELENGTHS in chart reading order, shape (24, n_lambda).

    'colour': colour-science's 'ColorChecker N Ohta'; 'isetcam': ISETCam's macbethChart.mat, given
    as ``data``: the .mat file itself or a folder holding spectral/isetcam/ (e.g. ../shared/data).
    """
    if source == "colour":
        sds = _colour().SDS_COLOURCHECKERS["ColorChecker N Ohta"]
        return np.stack([_resample(sd) for sd in sds.values()])
    if source == "isetcam":
        path = Path(data or "")
        return _isetcam_reflectances(path if path.suffix == ".mat" else path / "spectral" / "isetcam" / "macbethChart.mat")
    raise ClispError(f"unknown reflectance source {source!r}; expected one of {', '.join(REFLECTANCE_SOURCES)}")


ISETCAM_ORDER = [col * 4 + row for row in range(4) for col in range(6)]
"""ISETCam stores the 4 x 6 chart column by column; this puts it in reading order."""


def _isetcam_reflectances(path: Path) -> np.ndarray:
    """ISETCam's macbethChart.mat (wavelength column + 24 reflectances, column-major chart order)
    resampled to WAVELENGTHS, in reading order."""
    from scipy.io import loadmat       # deferred: scipy costs 0.15 s of start-up
    if not path.is_file():
        raise ClispError(f"{path}: no such file (ISETCam Macbeth reflectances)")
    mat = loadmat(str(path))
    wave = np.asarray(mat["wavelength"], dtype=np.float64).ravel()
    data = np.asarray(mat["data"], dtype=np.float64)
    if data.shape[0] != wave.size:
        data = data.T
    if data.shape[1] != 24:
        raise ClispError(f"{path}: expected 24 reflectances, found {data.shape[1]}")
    return np.stack([np.interp(WAVELENGTHS, wave, data[:, i]) for i in ISETCAM_ORDER])


@lru_cache(maxsize=None)
def mallett2019_basis() -> np.ndarray:
    """Mallett & Yuksel (2019) sRGB basis reflectances at WAVELENGTHS, shape (3, n_lambda).

    I. Mallett, C. Yuksel, "Spectral Primary Decomposition for Rendering with sRGB Reflectance",
    EGSR 2019 (doi:10.2312/sr.20191216), as shipped by colour-science
    (``colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019``, 380..780 nm step 5, read here at
    the 10 nm grid points). Each basis lies in [0, 1] and the three sum to 1 at every wavelength.
    """
    return _resample(_colour().recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019).T.copy()


def srgb_to_reflectance(rgb: np.ndarray) -> np.ndarray:
    """Reflectance spectra of linear sRGB colours by Mallett & Yuksel (2019), shape (..., n_lambda).

    rgb: (..., 3) linear sRGB, clipped to [0, 1] (the method's domain, where the spectra are valid
    reflectances in [0, 1]). R(lambda) = r B_r(lambda) + g B_g(lambda) + b B_b(lambda): what
    ``colour.recovery.RGB_to_sd_Mallett2019`` computes, vectorised over pixels.
    """
    return np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0) @ mallett2019_basis()


def camera_responses(refl: np.ndarray, kind: str) -> np.ndarray:
    """Photon-counting responses of reflectances (N, n_lambda) under D65, shape (N, 3), scaled so
    the brightest channel of a perfect white (R = 1) is 1."""
    s = sensitivities(kind)
    e = illuminant_d65()
    white = e @ s
    return (refl * e) @ s / white.max()


def true_srgb(refl: np.ndarray) -> np.ndarray:
    """Linear sRGB of reflectances (N, n_lambda) under D65 (CIE 1931 2-degree, Y(white) = 1), (N, 3)."""
    colour = _colour()
    cmfs = _resample(colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"])
    e = illuminant_d65()
    xyz = (refl * e) @ cmfs / (e @ cmfs[:, 1])
    return xyz @ XYZ_TO_SRGB.T


def white_balance(kind: str) -> np.ndarray:
    """Pass-1 multipliers from the simulated perfect white: gain_c = r_ref / r_c (L or G = 1), (3,)."""
    white = camera_responses(np.ones((1, WAVELENGTHS.size)), kind)[0]
    ref = 0 if kind == "lms" else 1
    return white[ref] / white


def fit_colour_matrix(cam_wb: np.ndarray, srgb: np.ndarray) -> np.ndarray:
    """3 x 3 M minimising |cam_wb M^T - srgb|^2 subject to M (1, 1, 1) = (1, 1, 1) (white-balanced
    white stays white). cam_wb, srgb: (N, 3). Solved per row as an equality-constrained LS."""
    n = cam_wb.shape[1]
    kkt = np.zeros((n + 1, n + 1))
    kkt[:n, :n] = cam_wb.T @ cam_wb
    kkt[:n, n] = kkt[n, :n] = 1.0
    rows = []
    for k in range(srgb.shape[1]):
        rhs = np.concatenate([cam_wb.T @ srgb[:, k], [1.0]])
        rows.append(np.linalg.solve(kkt, rhs)[:n])
    return np.array(rows)


@dataclass
class SpectralChart:
    """A spectral ColorChecker as seen by one camera kind.

    camera  H x W x 3 camera responses (photon counts, brightest white channel = 1).
    truth   H x W x 3 true linear sRGB of the same scene.
    wb      pass-1 multipliers (3,), from the perfect white.
    matrix  3 x 3, white-balanced camera -> linear sRGB, fitted over the 24 patches.
    rois    the 24 patch boxes (y0, y1, x0, x1) in reading order.
    """

    camera: np.ndarray
    truth: np.ndarray
    wb: np.ndarray
    matrix: np.ndarray
    rois: list[tuple[int, int, int, int]]


def spectral_colorchecker(kind: str, source: str = "colour", data: str | Path | None = None,
                          patch: int = 64, gap: int = 16, border: int = 16) -> SpectralChart:
    """The ColorChecker (layout of clisp.sim.charts.colorchecker) on a flat 18% grey background."""
    refl = reflectances(source, data)
    background = np.full((1, WAVELENGTHS.size), BACKGROUND)
    all_refl = np.vstack([refl, background])
    cam = camera_responses(all_refl, kind)
    srgb = true_srgb(all_refl)
    _, rois = colorchecker(patch=patch, gap=gap, border=border)
    height = rois[-1][1] + border
    width = rois[-1][3] + border
    index = np.full((height, width), len(refl))
    for i, (y0, y1, x0, x1) in enumerate(rois):
        index[y0:y1, x0:x1] = i
    wb = white_balance(kind)
    matrix = fit_colour_matrix(cam[:-1] * wb, srgb[:-1])
    return SpectralChart(camera=cam[index], truth=srgb[index], wb=wb, matrix=matrix, rois=rois)


def sensitivity_kind(cfa: Any) -> str:
    """The spectral sensitivities of a CFA's channels (SPECTRAL_KINDS): its ``spectral`` (the
    channel names, clisp.cfa), whatever its layout: 'lms' for L, M, S (the 4x4 CFA and LMS on the
    Bayer layout alike), 'bayer' (the Nikon D100's R, G, B) for R, G, B.

    >>> from clisp.cfa import cfa_from_name
    >>> [sensitivity_kind(cfa_from_name(n)) for n in ("lms", "bayer", "lms-bayer")]
    ['lms', 'bayer', 'lms']
    """
    spectral = getattr(cfa, "spectral", cfa.kind)
    return {"lms": "lms", "rgb": "bayer", "bayer": "bayer"}.get(spectral, spectral)


def simulate_spectral(cfa: str = "lms", gain: float | None = None, optics: str | None = "airy",
                      seed: int | None = 0, r0: float = 1.0, source: str = "colour",
                      data: str | Path | None = None, noise=None):
    """Simulate a raw of the spectral ColorChecker (the spectral path).

    Like :func:`clisp.sim.simulate.simulate`, but the scene is camera responses from spectra: no
    inverse ISP; WB from the simulated white; colour matrix fitted (see module docstring); truth =
    the chart's true linear sRGB through the same optics. Returns a SimResult.
    """
    cfa_obj = resolve_cfa(cfa)
    chart = spectral_colorchecker(sensitivity_kind(cfa_obj), source, data)
    return simulate_responses(chart.camera, chart.truth, cfa_obj, chart.wb, chart.matrix, gain=gain,
                              optics=optics, seed=seed, r0=r0, noise=noise,
                              scene=f"spectral colorchecker ({source}, D65)")


def simulate_responses(camera: np.ndarray, truth: np.ndarray, cfa, wb: np.ndarray, matrix: np.ndarray,
                       gain: float | None = None, optics: str | None = "airy", seed: int | None = 0,
                       r0: float = 1.0, noise=None, scene: str = "spectral scene (D65)"):
    """Simulate a raw from an image of camera responses (the spectral path for any scene).

    camera: H x W x 3 photon-counting responses (:func:`camera_responses`, brightest white channel
    = 1); truth: H x W x 3 true linear sRGB of the same scene; wb (3,) and matrix (3 x 3) go into
    the RawImage (e.g. those of :func:`spectral_colorchecker`). Optics, mosaic and noise as
    :func:`simulate_spectral`; the truth goes through the same optics. Returns a SimResult.
    """
    cfa_obj = resolve_cfa(cfa)
    noise = noise or NoiseModel()
    gain_value = None if gain is None else check_gain(gain)
    kernel = _optics_kernel(optics, r0)
    seed = _check_seed(seed)
    k_exp = 1.0   # responses are already scaled so the brightest channel of white is 1
    _, raw = optics_and_mosaic(camera, cfa_obj, kernel, np.eye(3) * k_exp)
    truth = truth.astype(np.float32) if kernel is None else apply_optics(truth, kernel).astype(np.float32)
    if gain_value is None:
        mosaic = (raw * noise.range_dn + float(noise.black_level)).astype(np.float32)
    else:
        mosaic = noise.sample(raw, gain_value, np.random.default_rng(seed))
    metadata = _metadata(cfa_obj, gain_value, noise, kernel, r0, seed, k_exp)
    metadata["scene"] = scene
    image = RawImage(data=mosaic, cfa=cfa_obj, black_level=np.full(cfa_obj.n_channels, float(noise.black_level)),
                     white_level=float(noise.white_level), wb=np.asarray(wb, dtype=np.float64),
                     colour_matrix=np.asarray(matrix, dtype=np.float64), exposure=1.0 / k_exp, wb2=np.ones(3),
                     metadata=metadata, source="simulated")
    return SimResult(raw=image, truth=truth)


def patch_delta_e(output: np.ndarray, truth: np.ndarray, rois: list[tuple[int, int, int, int]],
                  central: int = 32) -> np.ndarray:
    """CIEDE2000 per patch between the mean colours of the central ``central`` x ``central`` of each
    ROI in ``output`` and ``truth`` (both H x W x 3 linear sRGB), shape (len(rois),)."""
    def means(image: np.ndarray) -> np.ndarray:
        boxes = [central_box(r, central) for r in rois]
        return np.stack([image[y0:y1, x0:x1].reshape(-1, 3).mean(axis=0) for y0, y1, x0, x1 in boxes])

    lab_out = linear_srgb_to_lab(np.clip(means(output), 0, None)[None])
    lab_truth = linear_srgb_to_lab(np.clip(means(truth), 0, None)[None])
    return np.asarray(_colour().delta_E(lab_out, lab_truth, method="CIE 2000")).ravel()
