"""tools/lms_wins.py (issue 45) on scenes made in code: its protocol is the CLI's pipeline with
``--highlights off``, every camera gets the same search, and the section reads back from its CSV."""
from __future__ import annotations

import sys

import numpy as np

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import lms_wins  # noqa: E402  (tools/ is not a package)
from clisp.pipeline import build_pipeline  # noqa: E402
from clisp.sim.charts import dead_leaves  # noqa: E402


def test_the_same_search_for_every_camera():
    grid = lms_wins.search()
    labels = [d.label for d in grid]
    assert len(grid) == 18 and len(set(labels)) == 18
    assert sum(d.kind == "nlm" for d in grid) == 9 and lms_wins.DEFAULT.label in labels
    assert lms_wins.DEFAULT.params.luma == "paper" and lms_wins.DEFAULT.params.noise_scale == 1.0


def test_default_is_the_cli_pipeline_with_highlights_off():
    """A Shot through the default denoiser is what ``clisp process --highlights off --bad-pixels off``
    computes (no defect search: simulated raws have no defects; issue 44 came after the figures)."""
    scene = dead_leaves(96, seed=4) * 0.8
    for camera in (("bayer", "ri"), ("lms", "guided"), ("ML/LS", "ri")):
        shot = lms_wins.Shot(scene, camera, 8.0)
        want = build_pipeline(shot.raw, highlights="off", bad_pixels="off").run(shot.raw.data)
        np.testing.assert_array_equal(shot.output(lms_wins.DEFAULT), want, err_msg=str(camera))
        assert shot.output(lms_wins.search()[-1]).shape == want.shape          # the non-local class runs
    noiseless = lms_wins.Shot(scene, ("ML/LS", "ri"), None)
    np.testing.assert_array_equal(noiseless.output(lms_wins.DEFAULT),
                                  build_pipeline(noiseless.raw, highlights="off", bad_pixels="off").run(noiseless.raw.data))


def synthetic_run() -> lms_wins.Run:
    """A Run whose LMS camera trails Bayer by 1 dB at gain 4 and leads by 0.5 at 16 and 2 at 64."""
    sets, gains = ["Kodak", "McMaster"], [None, 4.0, 16.0, 64.0]
    grid = lms_wins.search()
    lead = {None: -1.0, 4.0: -1.0, 8.0: -0.2, 16.0: 0.5, 32.0: 1.0, 64.0: 2.0}
    judged, tuning, snr = {}, {}, {}
    for camera in lms_wins.CAMERAS:
        for d in grid:
            for g in lms_wins.TUNE_GAINS:
                tuning[("tuning", camera, d.label, g)] = 30.0 + (0.5 if d.label == "bilateral cfa x1" else 0.0)
        for g in lead:
            if g in gains or camera in (lms_wins.BAYER, lms_wins.LMS):
                for s in sets:
                    base = 30.0 - (g or 0) / 10
                    for label in (lms_wins.DEFAULT.label, "bilateral cfa x1"):
                        judged[(s, camera, label, g)] = base + (lead[g] if camera != lms_wins.BAYER else 0.0)
        for g in lms_wins.SNR_GAINS:
            for label in (lms_wins.DEFAULT.label, "bilateral cfa x1"):
                snr[(camera, label, g)] = 20.0 + (2.0 if camera == lms_wins.LMS else 0.0)
    best = {c: next(d for d in grid if d.label == "bilateral cfa x1") for c in lms_wins.CAMERAS}
    return lms_wins.Run(sets, gains, [8.0, 32.0], best, tuning, judged, snr, None, {s: 2 for s in sets}, {})


def test_crossover_and_the_goal():
    run = synthetic_run()
    assert lms_wins.crossover(run, "bilateral cfa x1", "bilateral cfa x1", "Kodak") == 16.0
    text = " ".join(lms_wins.paragraph(run))
    assert "leads Bayer from gain 16 on Kodak" in text and "**not met**" in text and "Kodak gain 4 -1.00" in text


def test_the_section_reads_back_from_its_csv(tmp_path):
    run = synthetic_run()
    path = tmp_path / "run.csv"
    lms_wins.toolkit.write_csv(lms_wins.csv_rows(run, "python tools/lms_wins.py", "facts"), path)
    again, command, facts = lms_wins.run_from_csv(path)
    assert (command, facts) == ("python tools/lms_wins.py", "facts")
    assert lms_wins.markdown(again, command, 0.0, facts) == lms_wins.markdown(run, command, 0.0, facts)


def test_parts_run_side_by_side_join_into_the_same_section(tmp_path):
    """``--cameras`` parts, each with its own CSV, read back together as the whole run."""
    run = synthetic_run()
    rows = lms_wins.csv_rows(run, "python tools/lms_wins.py", "facts")
    first = {lms_wins.BAYER[0], lms_wins.LMS[0]}
    paths = []
    for i, keep in enumerate((lambda r: r["cfa"] in first, lambda r: r["cfa"] not in first)):
        part = [rows[0]] + [r for r in rows[1:] if keep(r)]
        paths.append(tmp_path / f"part{i}.csv")
        lms_wins.toolkit.write_csv(part, paths[-1])
    again, command, facts = lms_wins.run_from_csv(paths)
    assert command == "python tools/lms_wins.py + python tools/lms_wins.py" and facts == "facts; facts"
    assert lms_wins.markdown(again, command, 0.0, facts) == lms_wins.markdown(run, command, 0.0, facts)


def test_a_missing_part_leaves_its_cameras_out():
    """The section from the Bayer and LMS part alone: no row of the other cameras, the goal still read."""
    run = synthetic_run()
    keep = (lms_wins.BAYER, lms_wins.LMS)
    run.best = {c: d for c, d in run.best.items() if c in keep}
    run.judged = {k: v for k, v in run.judged.items() if k[1] in keep}
    run.tuning = {k: v for k, v in run.tuning.items() if k[1] in keep}
    run.snr = {k: v for k, v in run.snr.items() if k[0] in keep}
    text = lms_wins.markdown(run, "python tools/lms_wins.py", 0.0, "facts")
    assert "| `ML/LS` (ri)" not in text and "| `lms` (guided)" in text and "**not met**" in text
