"""build_pipeline's decisions kept per camera and settings (clisp.pipeline.build.DECISIONS): a raw
of the same metadata and options gets the same stage objects, what its mosaic decides (the
highlight stage) stays its own, and nothing that read a mosaic or a file is kept."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from clisp.pipeline import build as build_module
from clisp.pipeline import build_pipeline
from clisp.modules.highlights.stage import HighlightClamp, Highlights
from clisp.sim.simulate import simulate


def scene(seed: int, bright: float = 1.0) -> np.ndarray:
    """A 48 x 64 sRGB scene: smooth colour ramps and noise, ``bright`` times."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:48, 0:64] / 64.0
    image = np.stack([0.2 + 0.5 * x, 0.3 + 0.4 * y, 0.5 - 0.3 * x * y], axis=-1) + 0.05 * rng.random((48, 64, 3))
    return np.clip(image * bright, 0.0, None)


@pytest.fixture
def fresh_memo(monkeypatch: pytest.MonkeyPatch) -> build_module.Memo:
    memo = build_module.Memo(16)
    monkeypatch.setattr(build_module, "DECISIONS", memo)
    return memo


@pytest.mark.parametrize("cfa", ["bayer", "lms"])
def test_a_raw_of_the_same_camera_and_settings_gets_the_same_stages(cfa: str, fresh_memo) -> None:
    first = simulate(scene(1), cfa=cfa, gain=4, seed=1).raw
    second = replace(simulate(scene(2), cfa=cfa, gain=4, seed=2).raw, metadata=dict(first.metadata))
    a = build_pipeline(first, preset="quality", output="srgb16")
    b = build_pipeline(second, preset="quality", output="srgb16")
    assert all(x is y for x, y in zip(a.stages, b.stages)) and len(a.stages) == len(b.stages)
    fresh_memo.clear()
    alone = build_pipeline(second, preset="quality", output="srgb16")
    assert a._key(True) == b._key(True) == alone._key(True)            # the same parameters, pickled
    np.testing.assert_array_equal(b.run(second.data), alone.run(second.data))


def test_what_the_mosaic_decides_stays_its_own(fresh_memo) -> None:
    """Clipped lights in the second raw of one camera and settings get their highlight stage; the
    first, unclipped, has none."""
    plain = simulate(scene(1), cfa="bayer", gain=4, seed=1).raw
    clipped = replace(simulate(scene(1, bright=3.0), cfa="bayer", gain=4, seed=1).raw,
                      metadata=dict(plain.metadata))
    assert not any(isinstance(s, (Highlights, HighlightClamp)) for s in build_pipeline(plain, preset="quality").stages)
    assert any(isinstance(s, (Highlights, HighlightClamp)) for s in build_pipeline(clipped, preset="quality").stages)
    assert len(fresh_memo) == 1


def test_other_settings_or_metadata_are_decided_again(fresh_memo) -> None:
    raw = simulate(scene(1), cfa="bayer", gain=4, seed=1).raw
    quality = build_pipeline(raw, preset="quality")
    assert build_pipeline(raw, preset="quality").stages[-1] is quality.stages[-1]
    other_gain = replace(raw, metadata={**raw.metadata, "gain": 8.0})
    assert build_pipeline(other_gain, preset="quality").stages[-1] is not quality.stages[-1]
    assert build_pipeline(raw, preset="balanced").stages[-1] is not quality.stages[-1]
    assert len(fresh_memo) == 3


def test_nothing_read_from_a_mosaic_or_a_file_is_kept(fresh_memo) -> None:
    """A raw without a noise model (a camera raw: its noise is estimated from the mosaic), an
    estimated white balance and the skip analysis are decided anew every time."""
    raw = simulate(scene(1), cfa="bayer", gain=4, seed=1).raw
    no_model = replace(raw, metadata={k: v for k, v in raw.metadata.items() if k != "noise"})
    build_pipeline(no_model, preset="quality")
    build_pipeline(raw, preset="quality", wb="auto")
    build_pipeline(raw, preset="quality", skip="auto")
    build_pipeline(raw, preset="quality", wb2="gray_world")
    assert len(fresh_memo) == 0
    build_pipeline(raw, preset="quality")
    assert len(fresh_memo) == 1
