"""Smoke test of tools/bench.py and tools/reproduce_paper.py on a small crop (no ../shared data)."""
from __future__ import annotations

import csv
import sys

import numpy as np


from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import bench  # noqa: E402  (tools/ is not a package)
import reproduce_paper  # noqa: E402


def test_pareto_front():
    points = {"a": (10.0, 30.0), "b": (1.0, 35.0), "c": (5.0, 29.0), "d": (10.0, 30.0)}
    assert bench.pareto(points) == {"a", "b", "d"}


def test_bench_small(tmp_path):
    from clisp.sim.charts import demo_chart

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


def _bench_peers_small(tmp_path, data, capsys) -> tuple[list[dict[str, str]], str]:
    """tools/bench_peers.py on 256 x 192, one run, clisp fast and rawpy only: (CSV rows, stdout)."""
    import bench_peers

    out = tmp_path / "peers.csv"
    code = bench_peers.main(["--size", "256x192", "--repeat", "1", "--only", "^clisp fast bayer|^rawpy",
                             "--data", str(data), "--work", str(tmp_path / "work"), "--csv", str(out),
                             "--results", str(tmp_path / "RESULTS.md"), "--quiet"])
    assert code == 0
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert [(r["tool"], r["preset"], r["output_format"]) for r in rows] == [
        ("clisp", "fast", "tif"), ("clisp", "fast", "exr"),
        ("rawpy", "LINEAR", "tif"), ("rawpy", "AHD", "tif"), ("rawpy", "DHT", "tif")]
    for r in rows:
        assert r["status"] == "ok" and r["runs"] == "1"
        assert 0 < float(r["median_s"]) < float("inf") and 0 < float(r["peak_rss_mib"]) < float("inf")
    assert 0 < float(rows[0]["vs rawpy LINEAR"]) < float("inf")
    section = (tmp_path / "RESULTS.md").read_text()
    assert section.count(bench_peers.MARK_START) == 1 and "rawpy LINEAR bayer→tif" in section
    return rows, capsys.readouterr().out


def test_bench_peers_simulated_bayer(tmp_path, capsys):
    """Without camera data (a user's clone): the Bayer input is a simulated raw of the demo chart."""
    _, text = _bench_peers_small(tmp_path, tmp_path / "no-data", capsys)
    assert "Input bayer: simulated Bayer raw" in text and "demo_chart.png" in text


def test_bench_peers_camera_bayer(tmp_path, capsys):
    """With ../shared/data: the Bayer input is the Canon D30's mosaic, tiled."""
    import bench_peers
    import pytest
    from toolkit import DEFAULT_DATA

    if not (DEFAULT_DATA / bench_peers.CAMERA_RAW).is_file():
        pytest.skip("no camera raw in ../shared/data")
    _, text = _bench_peers_small(tmp_path, DEFAULT_DATA, capsys)
    assert "RAW_CANON_D30_SRGB.CRW's CFA mosaic tiled" in text


def test_check_mem_small(tmp_path, capsys):
    """tools/check_mem.py on 400 x 300, fast, --mem 1G, EXR, without ../shared data (demo chart scene)."""
    import check_mem

    out = tmp_path / "mem.csv"
    code = check_mem.main(["--sizes", "400x300", "--presets", "fast", "--mems", "1G", "--formats", "exr",
                           "--cfas", "lms", "--data", str(tmp_path / "no-data"), "--work", str(tmp_path / "work"),
                           "--csv", str(out), "--results", str(tmp_path / "RESULTS.md"), "--quiet"])
    assert code == 0
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert [r["label"] for r in rows] == ["lms 0.12MP fast exr 1G"]
    row = rows[0]
    assert row["result"] == "pass" and row["exit"] == "0" and row["tiles"] != "0"
    assert 0 < float(row["peak_rss_mib"]) <= 1024 and float(row["headroom_mib"]) >= 0
    assert row["min_mem"]                       # the refusal at 150M named the minimum
    text = capsys.readouterr().out
    assert "demo_chart.png" in text and "1 of 1 exit 2" in text
    section = (tmp_path / "RESULTS.md").read_text()
    assert section.count(check_mem.MARK_START) == 1 and check_mem.SECTION_TITLE in section


def test_bench_demosaic_quality_small(tmp_path, capsys):
    """The LibRaw harness is checked against our own bilinear: LibRaw LINEAR on the same raw, with
    the same after-stages, must score the same (a shifted, scaled or mis-balanced LibRaw image
    would not); the denoised setting runs, and the CSV holds every method and summary row."""
    import bench_demosaic_quality as bdq

    out = tmp_path / "q.csv"
    assert bdq.main(["--sets", "deadleaves", "--dead-leaves", "1", "--dead-size", "96",
                     "--settings", "noiseless,16", "--bayer", "bilinear", "--libraw", "LINEAR",
                     "--csv", str(out)]) == 0
    with open(out) as f:
        rows = {(r["setting"], r["method"]): float(r["psnr_db"]) for r in csv.DictReader(f)}
    for setting in ("noiseless", "16"):
        assert abs(rows[(setting, "Bayer LibRaw LINEAR")] - rows[(setting, "Bayer clisp bilinear")]) < 0.05
        assert rows[(setting, "Bayer best (per image)")] >= rows[(setting, "Bayer clisp ri")]   # the default
        assert 10 < rows[(setting, "LMS clisp default")] < 60
    assert "lead: Bayer default - LibRaw best" in capsys.readouterr().out


def test_bench_demosaic_quality_lms_numpy_hook(capsys):
    """An --lms-numpy candidate replaces only the LMS demosaic: the default's own NumPy reference
    scores as the default pipeline (a wrong mosaic normalisation, phase or after-stage would not)."""
    import bench_demosaic_quality as bdq

    assert bdq.main(["--sets", "deadleaves", "--dead-leaves", "1", "--dead-size", "128",
                     "--settings", "noiseless", "--libraw", "",
                     "--lms-numpy", "bench_demosaic_quality:lms_default_reference"]) == 0
    text = capsys.readouterr().out
    scores = {line.rsplit(None, 1)[0].strip(): float(line.rsplit(None, 1)[1])
              for line in text.splitlines() if line.startswith("  LMS ")}
    assert abs(scores["LMS numpy lms_default_reference"] - scores["LMS clisp default"]) < 0.05


def test_docs_figures(tmp_path):
    """docs/model.md's figures redraw from clisp's definitions (no data files)."""
    import docs_figures
    assert docs_figures.main(["--out", str(tmp_path)]) == 0
    assert {p.name for p in tmp_path.glob("*.png")} == {"cfa.png", "spectrum.png", "noise.png"}


def test_bench_highlights_own_photos_and_gross_errors():
    """issue 25's own photos: every one has light past the clip point (truth over 1.0 at gain 1)
    and saturated colour (a channel under a quarter of another's); gross errors count pixels with a
    channel more than 0.5 off."""
    from bench_highlights import gross_errors, own_photos
    photos = own_photos(96)
    assert set(photos) == {"glossy spheres", "window and curtain", "sunset", "flowers"}
    for name, scene in photos.items():
        assert scene.shape == (96, 96, 3) and scene.max() > 1.0, name
        assert (scene.min(-1) < 0.25 * scene.max(-1)).any(), name
    truth = np.zeros((2, 2, 3))
    out = truth.copy()
    out[0, 0, 1], out[1, 1, 2] = 0.6, -0.4
    assert gross_errors(out, truth) == (1, 0.6)


def test_layout_sources_check(capsys):
    """tools/check_layout.py sources: no OpenCL source keeps a default for a host constant (#ifndef)
    and every function-level import in clisp/ says why it waits (issue 26); fails on either."""
    import check_layout
    assert check_layout.main(["sources"]) == 0, capsys.readouterr().out
