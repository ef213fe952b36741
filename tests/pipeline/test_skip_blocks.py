"""Flat paths at block granularity inside a tile (issue 30, item 2): clisp.pipeline.skip's ``mixed`` tiles
and their join (clisp.modules.block_blend)."""
from __future__ import annotations

import numpy as np
import pytest

from clisp.engine.executor import Pipeline
from clisp.engine.tiling import grid
from clisp.pipeline import build_pipeline
from clisp.sim.simulate import simulate
from clisp.pipeline.skip import PATH_FLAT, PATH_FULL, PATH_MIXED

from test_skip import smooth_scene, textured_scene


def strip_scene(h: int = 512, w: int = 512) -> np.ndarray:
    """A smooth gradient with a textured strip of 48 rows in the middle (the striped sky, small)."""
    scene = smooth_scene(h, w)
    scene[h // 2 - 24:h // 2 + 24] = textured_scene(h, w)[h // 2 - 24:h // 2 + 24]
    return scene


def mixed_pipeline(monkeypatch: pytest.MonkeyPatch, cfa: str = "lms", gain: float = 1, scene=None):
    """A skip pipeline on the strip scene that mixes wherever a tile holds texture: on images this
    small the detail path's halo makes mixing cost more than it saves, so MIX_GAIN is lifted."""
    import clisp.pipeline.skip as skip
    monkeypatch.setattr(skip, "MIX_GAIN", 100.0)
    sim = simulate(strip_scene() if scene is None else scene, cfa=cfa, gain=gain, seed=4)
    pipe = build_pipeline(sim.raw, skip=True, demosaic=None if cfa == "lms" else "dlmmse")
    return sim, pipe


def composite(pipe, raw, detail: str = PATH_FULL) -> np.ndarray:
    """The whole image on the flat path and on the ``detail`` path, joined by the block blend's
    weights: what every mixed tile of that detail path must equal, whatever the tiling."""
    sk = pipe.skipper
    flat = Pipeline(raw.cfa, sk.paths[PATH_FLAT]).run(raw.data, tile=0)
    full = Pipeline(raw.cfa, sk.paths[detail]).run(raw.data, tile=0)
    w = sk.block_blend().weight(0, 0, *raw.shape)[..., None]
    return np.where(w >= 1, full, np.where(w <= 0, flat, flat + w * (full - flat)))


@pytest.mark.parametrize("cfa", ["lms", "bayer"])
def test_mixed_tiles_equal_the_whole_image_joined(cfa: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Per plan, tiled equals whole: each mixed tile equals the whole image's flat and full paths
    joined by the weights, at any tiling; flat tiles equal the whole flat path."""
    sim, pipe = mixed_pipeline(monkeypatch, cfa)
    raw = sim.raw
    joined = {p: composite(pipe, raw, p) for p in pipe.skipper.paths if p != PATH_FLAT}
    flat = Pipeline(raw.cfa, pipe.skipper.paths[PATH_FLAT]).run(raw.data, tile=0)
    for tile in (0, 128, 192):
        out = pipe.run(raw.data, tile=tile)
        plan = pipe.skip_plan
        assert PATH_MIXED in plan.counts, plan.explain()
        for c in plan.choices:
            t = c.tile
            region = (slice(t.y0, t.y0 + t.h), slice(t.x0, t.x0 + t.w))
            if c.path == PATH_MIXED:
                assert c.rects
                np.testing.assert_allclose(out[region], joined[c.detail][region], atol=3e-5, rtol=0,
                                           err_msg=f"tile {tile}, {c.detail}")
            elif c.path == PATH_FLAT:
                np.testing.assert_allclose(out[region], flat[region], atol=3e-5, rtol=0)


def test_mixed_tiles_match_the_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    sim, pipe = mixed_pipeline(monkeypatch, "bayer", scene=strip_scene(256, 256))
    ocl = pipe.run(sim.raw.data, tile=0)
    assert pipe.skip_plan.counts == {PATH_MIXED: 1}, pipe.skip_plan.explain()
    ref = pipe.run(sim.raw.data, tile=0, backend="reference")
    np.testing.assert_allclose(ocl, ref, atol=2e-4, rtol=0)


@pytest.mark.parametrize("gain", [1, 16])
def test_no_seam_where_the_paths_join(gain: float, monkeypatch: pytest.MonkeyPatch) -> None:
    """Across the join, the output's error against the truth changes as smoothly as inside the
    blocks: the row-to-row change of the error's 8-row means (a step would be one large change)
    is no larger across block seams than within blocks; the join is within the flat path's and
    the full path's errors; the flat side is no worse than no-skip."""
    sim, pipe = mixed_pipeline(monkeypatch, "lms", gain)
    out = pipe.run(sim.raw.data, tile=0)
    plan = pipe.skip_plan
    assert plan.counts == {PATH_MIXED: 1}
    pipe.skipper.enabled = False
    full = pipe.run(sim.raw.data, tile=0)
    err = (out - sim.truth)[:, 16:-16].mean(axis=1)              # (rows, 3): mean error per row
    means = err.reshape(-1, 8, 3).mean(axis=1)                   # 8-row means
    steps = np.abs(np.diff(means, axis=0)).max(axis=1)           # between neighbouring 8-row bands
    seam = np.array([(k + 1) * 8 % 64 == 0 for k in range(len(steps))])
    rect = plan.choices[0].rects[0]
    near = np.array([rect.y0 - 32 <= (k + 1) * 8 < rect.y0 + rect.h + 32 for k in range(len(steps))])
    print(f"8-row mean steps: across seams near the join {steps[seam & near].max():.2e}, "
          f"within blocks {steps[~seam].max():.2e}")
    assert steps[seam & near].max() <= steps[~seam].max()
    outside = np.ones(out.shape[0], dtype=bool)
    outside[rect.y0:rect.y0 + rect.h] = False
    e_skip = np.mean((out[outside] - sim.truth[outside]) ** 2)
    e_full = np.mean((full[outside] - sim.truth[outside]) ** 2)
    assert e_skip <= e_full * 1.02, (e_skip, e_full)


def test_plan_mixes_only_where_texture_is_and_it_pays(monkeypatch: pytest.MonkeyPatch) -> None:
    import clisp.pipeline.skip as skip
    sim, pipe = mixed_pipeline(monkeypatch)
    sk = pipe.skipper
    plan = sk.plan(grid(512, 512, 512, 512))
    (c,) = plan.choices
    assert c.path == PATH_MIXED and c.detail == PATH_FULL
    texture_rows = np.flatnonzero(sk.block_blend().mask.any(axis=1))
    (r,) = c.rects                                      # one strip: one rectangle, the whole width
    assert r.x0 == 0 and r.w == 512
    assert r.y0 == (texture_rows[0] - 1) * 64 and r.y0 + r.h == (texture_rows[-1] + 2) * 64
    assert "mixed" in plan.explain() and "rectangles" in plan.explain()
    monkeypatch.setattr(skip, "MIX_GAIN", 0.1)          # mixing that does not pay: the detail path alone
    assert {c.path for c in sk.plan(grid(512, 512, 512, 512)).choices} == {PATH_FULL}
    sk.enabled = False                                  # --no-skip: never mixed
    assert {c.path for c in sk.plan(grid(512, 512, 512, 512)).choices} == {PATH_FULL}
    sim2, pipe2 = mixed_pipeline(monkeypatch, scene=smooth_scene(512, 512))
    assert {c.path for c in pipe2.skipper.plan(grid(512, 512, 512, 512)).choices} == {PATH_FLAT}


def test_skipping_is_off_where_the_device_is_not_the_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a GPU the full path's device time is less than the analysis: the CLI's default ('auto')
    analyses nothing there and says why; skip=True still forces the plan (tests, warm-up)."""
    import clisp.pipeline.skip as skip
    from types import SimpleNamespace
    from clisp.engine.runtime import get_runtime
    from clisp.pipeline import SKIP_WHERE_IT_PAYS
    cl = get_runtime().cl
    cpu = SimpleNamespace(cl=cl, device=SimpleNamespace(type=cl.device_type.CPU, name="Some CPU"))
    gpu = SimpleNamespace(cl=cl, device=SimpleNamespace(type=cl.device_type.GPU, name="Some GPU "))
    assert skip.on_host_cpu(cpu) and skip.on_host_cpu(None) and not skip.on_host_cpu(gpu)
    assert skip.why_not_skip(cpu) == "" and "Some GPU" in skip.why_not_skip(gpu)
    raw = simulate(strip_scene(256, 256), cfa="lms", gain=1, seed=0).raw
    monkeypatch.setattr(skip, "on_host_cpu", lambda rt: False)
    auto = build_pipeline(raw, skip=SKIP_WHERE_IT_PAYS)
    assert auto.skipper is None and "not the host's CPU" in auto.skip_off
    assert "no scene analysis (skipping is off on" in skip.explain_run(auto, auto.stats)
    assert build_pipeline(raw, skip=True).skipper is not None
    monkeypatch.setattr(skip, "on_host_cpu", lambda rt: True)
    assert build_pipeline(raw, skip=SKIP_WHERE_IT_PAYS).skipper is not None


def test_skipping_is_off_where_there_is_no_flat_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """Behind residual interpolation (the Bayer quality preset) there is no flat path, and the
    denoiser's lighter paths alone never paid for the analysis: the default analyses nothing."""
    import clisp.pipeline.skip as skip
    from clisp.pipeline import SKIP_WHERE_IT_PAYS
    monkeypatch.setattr(skip, "on_host_cpu", lambda rt: True)       # the rule on a CPU, whatever this machine's device
    raw = simulate(strip_scene(256, 256), cfa="bayer", gain=1, seed=0).raw
    quality = build_pipeline(raw, skip=SKIP_WHERE_IT_PAYS)
    assert quality.skipper is None and "no flat path" in quality.skip_off
    assert build_pipeline(raw, skip=SKIP_WHERE_IT_PAYS, demosaic="dlmmse").skipper is not None
    assert build_pipeline(raw, skip=True).skipper is not None


@pytest.mark.parametrize("cfa,preset", [("lms", "balanced"), ("bayer", "balanced"), ("lms", "quality")])
def test_mixed_tiles_with_clipping_odd_sizes_and_presets(cfa: str, preset: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A clipped highlight inside the textured strip (the highlight stage on both paths), an image
    whose sides are no multiple of the blocks or the CFA's period, the balanced preset's demosaics:
    each mixed tile still equals the whole image's two paths joined, at two tilings."""
    import clisp.pipeline.skip as skip
    monkeypatch.setattr(skip, "MIX_GAIN", 100.0)
    scene = strip_scene(456, 390)
    scene[220:232, 100:130] = 4.0                                  # clipped, inside the strip
    sim = simulate(scene, cfa=cfa, gain=4, seed=9)
    raw = sim.raw
    pipe = build_pipeline(raw, skip=True, preset=preset)
    assert "highlights" in [s.name for s in pipe.skipper.paths[PATH_FLAT]]
    joined = {p: composite(pipe, raw, p) for p in pipe.skipper.paths if p != PATH_FLAT}
    for tile in (0, 160):
        out = pipe.run(raw.data, tile=tile)
        plan = pipe.skip_plan
        mixed = [c for c in plan.choices if c.path == PATH_MIXED]
        assert mixed, plan.explain()
        for c in mixed:
            t = c.tile
            region = (slice(t.y0, t.y0 + t.h), slice(t.x0, t.x0 + t.w))
            np.testing.assert_allclose(out[region], joined[c.detail][region], atol=5e-5, rtol=0,
                                       err_msg=f"{cfa} {preset} tile {tile}")
        assert np.isfinite(out).all()


def test_explain_reports_mixed_tiles_and_device_time_per_path(tmp_path, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    """``clisp process --explain`` on a sky with a textured strip: the mixed tile, its rectangles,
    and the device time each path took, measured in the run (issue 30, item 3)."""
    import clisp.pipeline.skip as skip
    from clisp.app.cli import main
    from clisp.io.rawfile import write_raw
    monkeypatch.setattr(skip, "MIX_GAIN", 100.0)
    monkeypatch.setattr(skip, "on_host_cpu", lambda rt: True)     # the CLI's default skips only there
    raw_path = tmp_path / "strip.dng"
    write_raw(raw_path, simulate(strip_scene(), cfa="lms", gain=1, seed=0).raw)
    assert main(["process", str(raw_path), "-o", str(tmp_path / "a.exr"), "--explain"]) == 0
    out = capsys.readouterr().out
    for expected in ("mixed ", "rectangles", "device time per path", "mixed: flat path", "mixed: full path",
                     "mixed: join", "time saved"):
        assert expected in out, f"{expected!r} missing from --explain:\n{out}"


def test_warm_builds_the_join(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``clisp info --warm`` also runs a mixed tile, so a first real run that mixes builds no
    program the warm-up did not (the join's kernel, the planar denoiser of the detail path) at
    the warm-up's noise (a denoiser program also depends on the noise: clisp.app.warm's docstring)."""
    import clisp.pipeline.skip as skip
    from clisp.engine.runtime import get_runtime
    from clisp.pipeline import process_file
    from clisp.app.warm import WARM_GAIN, warm_kernels
    rt = get_runtime()
    warm_kernels(("quality",), ("lms",), report=None)
    built = set(rt.programs.built)
    monkeypatch.setattr(skip, "MIX_GAIN", 100.0)
    raw = simulate(strip_scene(320, 256), cfa="lms", gain=WARM_GAIN, seed=3).raw
    process_file(raw, tmp_path / "x.tif", preset="quality", skip=True, explain=(explained := {}))
    assert PATH_MIXED in explained["pipeline"].skip_plan.counts
    assert set(rt.programs.built) == built
