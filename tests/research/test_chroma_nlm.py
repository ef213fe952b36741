"""The non-local chroma denoiser study (research.chroma_nlm, issue 45): the same frame as clisp's
bilateral denoiser, so without noise it is the colour matrix, it never touches the luminance, and on
noise it flattens chroma without moving a flat field's colour; its patch distance keeps a colour
edge the luminance does not mark."""
import numpy as np

from clisp.modules.chroma_denoise.stage import NoiseTable, chroma_split, lms_space
from clisp.sim.colorimetry import P_LMS
from research.chroma_nlm import NLMParams, _box, chroma_nlm

SPACE = lms_space(P_LMS)


def table(std: float) -> NoiseTable:
    """White noise of std ``std`` at level 0 in every plane (floor only): level j's block means have
    std / 2^j, its details std / 2^(j+1)."""
    approx = np.zeros((4, 4, 2))
    detail = np.zeros((4, 4, 3, 2))
    for j in range(4):
        approx[j, :, 1] = (std / 2 ** j) ** 2
        detail[j, :, :, 1] = (std / 2 ** (j + 1)) ** 2
    return NoiseTable(approx, detail)


def test_box_is_the_window_mean():
    a = np.arange(30.0).reshape(5, 6)
    np.testing.assert_allclose(_box(a, 1)[0, 0], a[:3, :3].mean())
    assert _box(a, 1).shape == (3, 4)


def test_noiseless_is_the_colour_matrix():
    rng = np.random.default_rng(0)
    cam = rng.uniform(0.1, 0.9, (40, 44, 3))
    out = chroma_nlm(cam, SPACE, NoiseTable.zero(3, 3))
    np.testing.assert_allclose(out, np.einsum("ij,hwj->hwi", P_LMS, cam), atol=1e-9)


def test_chroma_noise_reduced_on_a_flat_field():
    """Noise in the chroma planes falls by more than half, the field's colour stays (no bias)."""
    rng = np.random.default_rng(1)
    flat = np.full((64, 64, 3), 0.4)
    cam = flat + 0.02 * rng.standard_normal(flat.shape)
    out = chroma_nlm(cam, SPACE, table(0.02 * 6.1))          # R-Y's noise is ~6x the camera channels'
    before = np.einsum("ij,hwj->hwi", P_LMS, cam)
    c_out = chroma_split(np.moveaxis(out, -1, 0), np.eye(3) - 1.0 / 3.0)[:, 8:-8, 8:-8]
    c_in = chroma_split(np.moveaxis(before, -1, 0), np.eye(3) - 1.0 / 3.0)[:, 8:-8, 8:-8]
    assert c_out.std(axis=(1, 2)).max() < 0.5 * c_in.std(axis=(1, 2)).min()
    np.testing.assert_allclose(out.mean(axis=(0, 1)), before.mean(axis=(0, 1)), atol=2e-3)


def test_patches_keep_an_isoluminant_edge():
    """Two halves of equal luminance and different colour, with noise: each half's mean colour stays
    near its own (the patch distance sees the edge), within a third of the step."""
    rng = np.random.default_rng(2)
    cam = np.full((64, 64, 3), 0.4)
    cam[:, 32:] = (0.41, 0.39, 0.4)                     # Y = (L + M) / 2 the same; R - Y up 0.086
    noisy = cam + 0.004 * rng.standard_normal(cam.shape)
    out = chroma_nlm(noisy, SPACE, table(0.004 * 6.1), NLMParams(patch=1, patch_luma=0))
    truth = np.einsum("ij,hwj->hwi", P_LMS, cam)
    step = np.abs(truth[:, 40] - truth[:, 20]).max()
    assert np.abs(out[8:-8, 29] - truth[8:-8, 29]).mean(axis=0).max() < step / 3
    assert np.abs(out[8:-8, 34] - truth[8:-8, 34]).mean(axis=0).max() < step / 3
