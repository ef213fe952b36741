"""Gray-world white balance on the raw mosaic (pass 1 fallback)."""
from __future__ import annotations

import numpy as np
import pytest

from clisp.cfa import bayer_cfa, lms_cfa
from clisp.errors import ClispError
from clisp.white_balance import gray_world_gains


@pytest.mark.parametrize("cfa", [bayer_cfa("GRBG"), lms_cfa()], ids=lambda c: c.name)
def test_gray_world_recovers_channel_gains(cfa) -> None:
    rng = np.random.default_rng(1)
    true_gains = np.array([2.0, 1.0, 1.6]) if cfa.kind == "bayer" else np.array([1.0, 1.2, 3.1])
    scene = rng.uniform(0.05, 0.4, size=(64, 96))           # the same grey world in every channel
    channel = cfa.channel_map(64, 96)
    data = 64 + 900 * scene / true_gains[channel]
    data[10:14, 20:24] = 1023                               # a clipped highlight must not bias it
    gains = gray_world_gains(data, cfa, np.full(3, 64.0), 1023)
    assert np.allclose(gains, true_gains, rtol=0.03)


def test_all_clipped_is_an_error() -> None:
    with pytest.raises(ClispError, match="clipped"):
        gray_world_gains(np.full((8, 8), 1023.0), bayer_cfa(), np.zeros(3), 1023)
