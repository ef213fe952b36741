"""Smoke test of tools/bench.py and tools/reproduce_paper.py on a small crop (no ../shared data)."""
from __future__ import annotations

import csv
import sys
from pathlib import Path


TOOLS = Path(__file__).resolve().parents[1] / "tools"
sys.path.insert(0, str(TOOLS))

import bench  # noqa: E402  (tools/ is not a package)
import reproduce_paper  # noqa: E402


def test_pareto_front():
    points = {"a": (10.0, 30.0), "b": (1.0, 35.0), "c": (5.0, 29.0), "d": (10.0, 30.0)}
    assert bench.pareto(points) == {"a", "b", "d"}


def test_bench_small(tmp_path):
    from clisp.charts import demo_chart

    scene = demo_chart().image[:128, :160]
    wanted = {"clisp lms fast", "clisp bayer fast", "cd bilinear", "rawpy LINEAR"}
    methods = [m for m in bench.all_methods() if m.name in wanted]
    assert {m.name for m in methods} == wanted
    scores = bench.quality(methods, [("crop", scene)], [8.0], verbose=False)
    # the same bilinear demosaic on the same mosaic with the same WB and matrix: the same PSNR
    ours = scores[("clisp bayer fast", 8.0)]
    assert abs(scores[("cd bilinear", 8.0)] - ours) < 0.05
    assert abs(scores[("rawpy LINEAR", 8.0)] - ours) < 0.2
    speeds = bench.speed(methods, scene, (64, 96), 1, verbose=False)
    assert all(v > 0 for v in speeds.values())
    rows = bench.rows_for(methods, scores, speeds, [8.0])
    assert any(r["pareto"] for r in rows)
    bench.write_csv(rows, tmp_path / "b.csv")
    with open(tmp_path / "b.csv") as f:
        assert len(list(csv.DictReader(f))) == len(methods)
    assert bench.summary(rows)
    bench.plot(rows, tmp_path / "b.png", "smoke")
    assert (tmp_path / "b.png").stat().st_size > 0


def test_reproduce_paper_markdown():
    rp = reproduce_paper
    rows = [dict(method="clisp lms fast", cfa="lms", family="clisp preset", gain=g, psnr=30.0, mp_per_s=5.0,
                 pareto=True, pareto_same_cfa=True) for g in (1.0, 8.0)]
    result = dict(rows=rows, scenes=["x"], speed_scene="x", speed_shape=(8, 8), repeat=1, device="cpu")
    text = "\n".join(rp.md_bench(result, "bench.csv", "bench.png"))
    assert "30.00 * +" in text and "bench.png" in text
