"""A colour matrix fused into a demosaic's last kernel: the shared part of the demosaic stages whose
last kernel applies a 3 x 3 matrix to R, G, B and can write the host's interleaved layout (DLMMSE, RI).

A stage using it is a dataclass with the fields ``matrix`` (3 x 3 or None: identity) and
``interleaved`` (bool), and lists this mixin before Stage among its bases, so that its ``fuse`` and
``with_interleaved_output`` are these.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..colour.stage import ColourMatrix


class FusedColourMatrix:
    """Mixin: a following ColourMatrix runs inside the stage's last kernel (same maths, one pass fewer)."""

    matrix: np.ndarray | None
    interleaved: bool

    def output_matrix(self) -> np.ndarray:
        """The 3 x 3 matrix the last kernel applies (float64; the identity when none was fused)."""
        return np.eye(3) if self.matrix is None else np.asarray(self.matrix, dtype=np.float64)

    def apply_output_matrix(self, rgb: np.ndarray) -> np.ndarray:
        """The reference's H x W x 3 output times the fused matrix (unchanged when none was fused)."""
        return rgb if self.matrix is None else np.einsum("ij,hwj->hwi", self.output_matrix(), rgb)

    def fuse(self, following: Any) -> Any:
        """This stage with a following ColourMatrix folded into its matrix; None for any other stage
        or once the output is interleaved."""
        if isinstance(following, ColourMatrix) and not self.interleaved:
            return replace(self, matrix=np.asarray(following.matrix, dtype=np.float64) @ self.output_matrix())
        return None

    def with_interleaved_output(self) -> Any:
        """This stage writing H x W x 3 (the host layout) instead of planes."""
        return replace(self, interleaved=True)
