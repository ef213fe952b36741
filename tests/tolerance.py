"""The suite's one rule for comparing a float32 OpenCL result with its float64 NumPy reference.

|opencl - reference| <= TOL * max(1, |reference|): relative where values exceed 1, absolute below
(raw inputs in DN, outputs linear or sRGB-encoded in about [0, 1]). A test that needs a looser bound
passes ``tol`` and says why where it does.
"""
from __future__ import annotations

import numpy as np

TOL = 1e-5


def assert_close(actual: np.ndarray, reference: np.ndarray, what: str = "", tol: float = TOL) -> None:
    """Assert equal shapes, finite values and the tolerance rule; name the worst pixel on failure."""
    actual = np.asarray(actual)
    reference = np.asarray(reference, dtype=np.float64)
    assert actual.shape == reference.shape, f"{what}: shape {actual.shape} != {reference.shape}"
    assert np.all(np.isfinite(actual)), f"{what}: non-finite output"
    err = np.abs(actual.astype(np.float64) - reference) / np.maximum(1.0, np.abs(reference))
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() <= tol, (f"{what}: max scaled error {err.max():.3g} at {worst} "
                              f"(opencl {actual[worst]!r}, reference {reference[worst]!r})")
