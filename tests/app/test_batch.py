"""clisp batch (clisp.app.batch): Dask clusters on loopback, failure isolation, the manifest, resume.

Raws are simulated in code (64 x 96, some larger for the kill test); corrupt ones are a truncated
raw and a garbage file. Every wait has a limit: cluster start-up (START), results (RESULTS) and
the CLI subprocesses (CLI_LIMIT), so a broken Dask never hangs the suite.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from paths import REPO
from clisp.app.batch import BatchSettings, read_manifest, run_batch
from clisp.io.imageio import read_image
from clisp.io.rawfile import write_raw
from clisp.sim.simulate import simulate

pytest.importorskip("distributed")

START, RESULTS, CLI_LIMIT = 60.0, 120.0, 150.0
ROOT = REPO


def make_raws(folder: Path, count: int, shape: tuple[int, int], corrupt: bool = True) -> list[Path]:
    """``count`` simulated raws (alternately Bayer and LMS, gain 4, random blocks), plus a
    truncated raw and a garbage file when ``corrupt``. Returns the good ones."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    h, w = shape
    good = []
    for i in range(count):
        scene = rng.random((h // 8, w // 8, 3)).repeat(8, 0).repeat(8, 1)
        path = folder / f"img{i:02d}.dng"
        write_raw(path, simulate(scene, "lms" if i % 2 else "bayer", gain=4, seed=i, optics="none").raw)
        good.append(path)
    if corrupt:
        data = good[0].read_bytes()
        (folder / "truncated.dng").write_bytes(data[: len(data) // 2])
        (folder / "garbage.dng").write_bytes(os.urandom(4096))
    return good


@pytest.fixture(scope="module")
def external_cluster():
    """A Dask cluster of 2 worker processes on loopback, started here: clisp reaches it by address."""
    from distributed import LocalCluster
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None)
    try:
        yield cluster
    finally:
        cluster.close()


def by_output(records: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in records:
        out.setdefault(r["output"], []).append(r)
    return out


def test_batch_on_cluster_manifest_resume_and_changed_settings(tmp_path: Path, external_cluster) -> None:
    good = make_raws(tmp_path / "in", 18, (64, 96))
    outdir = tmp_path / "out"
    address = external_cluster.scheduler_address
    workers = set(external_cluster.scheduler_info["workers"])
    summary = run_batch([tmp_path / "in"], outdir, BatchSettings(), scheduler=address,
                        start_timeout=START, timeout=RESULTS)
    assert (summary.ok, summary.errors, summary.skipped) == (18, 2, 0)
    records = read_manifest(outdir / "manifest.jsonl")
    assert len(records) == 20
    errors = [r for r in records if r["status"] == "error"]
    assert sorted(Path(r["input"]).name for r in errors) == ["garbage.dng", "truncated.dng"]
    for r in errors:
        assert Path(r["input"]).name in r["error"] and "\n" not in r["error"] and len(r["error"]) > 30
    for r in records:                       # the manifest names the worker that ran each file
        assert r["worker"] in workers and r["settings"] == BatchSettings().digest() and r["seconds"] >= 0
    for path in good:
        image, is_float = read_image(outdir / f"{path.stem}.exr")
        assert is_float and image.shape == (64, 96, 3) and np.isfinite(image).all()
    assert not list(outdir.glob(".*partial*")) and not (outdir / "truncated.exr").exists()
    first = {r["output"]: r for r in records if r["status"] == "ok"}
    mtimes = {p.name: p.stat().st_mtime_ns for p in outdir.glob("*.exr")}

    # same settings: nothing redone; the corrupt files are tried (and fail) again
    summary = run_batch([tmp_path / "in"], outdir, BatchSettings(preset="quality"), scheduler=address,
                        start_timeout=START, timeout=RESULTS)
    assert (summary.ok, summary.errors, summary.skipped) == (0, 2, 18)
    assert {p.name: p.stat().st_mtime_ns for p in outdir.glob("*.exr")} == mtimes
    # a damaged output (same size, other bytes) is found by its hash and redone
    damaged = outdir / "img03.exr"
    pixels = read_image(damaged)[0]
    data = bytearray(damaged.read_bytes())
    data[-1] ^= 0xFF
    damaged.write_bytes(bytes(data))
    summary = run_batch(good, outdir, BatchSettings(), scheduler=address, start_timeout=START, timeout=RESULTS)
    assert (summary.ok, summary.skipped) == (1, 17)
    redone = read_manifest(outdir / "manifest.jsonl")[-1]
    assert redone["output"] == "img03.exr" and redone["size"] == first["img03.exr"]["size"]
    assert np.array_equal(read_image(damaged)[0], pixels)    # (the EXR header has a capture date)

    # changed settings: every output redone
    summary = run_batch(good, outdir, BatchSettings(preset="fast"), scheduler=address,
                        start_timeout=START, timeout=RESULTS)
    assert (summary.ok, summary.errors, summary.skipped) == (18, 0, 0)
    last = {r["output"]: r for r in read_manifest(outdir / "manifest.jsonl")[-18:]}
    assert all(r["settings"] == BatchSettings(preset="fast").digest() != first[k]["settings"] for k, r in last.items())
    assert all(r["status"] == "ok" and r["mtime_ns"] > first[k]["mtime_ns"] for k, r in last.items())


def test_cli_batch_killed_then_resumed(tmp_path: Path) -> None:
    """``clisp batch`` on its own 2-worker local cluster, killed (SIGKILL to its process group:
    client, scheduler and workers) once some files are in the manifest, then run again."""
    make_raws(tmp_path / "in", 16, (384, 512), corrupt=False)
    outdir, manifest = tmp_path / "out", tmp_path / "out" / "manifest.jsonl"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    command = [sys.executable, "-m", "clisp", "batch", str(tmp_path / "in"), "-o", str(outdir), "--workers", "2"]
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True)
    deadline = time.monotonic() + CLI_LIMIT
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            if sum(r["status"] == "ok" for r in read_manifest(manifest)) >= 3:
                break
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=30)
    before = read_manifest(manifest)
    finished = {r["output"]: r for r in before if r["status"] == "ok"}
    print(f"killed after {len(finished)} of 16 files; per file {[r['seconds'] for r in finished.values()]}")
    assert 3 <= len(finished) < 16, f"kill came at {len(finished)} of 16 files: {before}"

    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=CLI_LIMIT)
    assert result.returncode == 0, result.stdout + result.stderr
    after = read_manifest(manifest)[len(before):]
    assert len(after) == 16
    skipped = {r["output"] for r in after if r["status"] == "skipped"}
    redone = {r["output"] for r in after if r["status"] == "ok"}
    assert skipped == set(finished)                          # nothing finished is redone
    assert redone == {f"img{i:02d}.exr" for i in range(16)} - skipped   # nothing is lost
    assert "16 ok" not in result.stdout and f"{len(skipped)} skipped" in result.stdout
    for r in after:
        assert (outdir / r["output"]).stat().st_size == r["size"]
    assert not list(outdir.glob(".*partial*"))               # the killed run's temporaries are gone
    assert json.loads(manifest.read_text().splitlines()[-1])["run"] != before[-1]["run"]


def test_paper_sweep_on_cluster_matches_serial(tmp_path: Path, external_cluster) -> None:
    """tools/reproduce_paper.py --scheduler: the Table 1 sweep's items run on the cluster (tools'
    code shipped by value, one Runner per worker) and give the serial numbers exactly."""
    sys.path.insert(0, str(ROOT / "tools"))
    import paper_tables as pt
    import reproduce_paper
    from clisp.sim.charts import demo_chart
    from clisp.io.imageio import write_image
    from clisp.modules.chroma_denoise.stage import ChromaDenoiseParams
    scene = tmp_path / "scene.png"
    write_image(scene, demo_chart().image[:64, :96], encoded=False)
    runner = pt.Runner(ChromaDenoiseParams(), None)
    items = [(scene, gain, [("bayer", "bilinear"), ("lms", "bilinear")]) for gain in (4, 8)]
    serial = pt.serial(pt.table1_item, items, runner)
    with reproduce_paper.sweep_mapper(external_cluster.scheduler_address) as mapper:
        remote = mapper(pt.table1_item, items, runner, timeout=RESULTS)
    assert remote == serial and len(serial[0]) == 4


def test_one_worker_per_gpu(monkeypatch) -> None:
    """A machine whose OpenCL lists GPUs starts one local worker per GPU (not one per CPU), each on
    its own GPU; a CPU device (CLISP_DEVICE=cpu, or no GPU) one per CPU (issue 41, item 6)."""
    from types import SimpleNamespace
    import pyopencl as cl
    import clisp.app.batch as batch
    import clisp.engine.runtime as runtime
    gpu = SimpleNamespace(type=cl.device_type.GPU, name="GPU")
    gpu2 = SimpleNamespace(type=cl.device_type.GPU, name="GPU 2")
    cpu = SimpleNamespace(type=cl.device_type.CPU, name="CPU")
    nvidia, pocl = SimpleNamespace(name="NVIDIA CUDA"), SimpleNamespace(name="Portable Computing Language")
    found = [(0, 0, nvidia, gpu), (0, 1, nvidia, gpu2), (1, 0, pocl, cpu)]
    monkeypatch.setattr(runtime, "list_devices", lambda: found)
    monkeypatch.delenv("CLISP_DEVICE", raising=False)
    assert batch.local_gpus() == ["0:0", "0:1"] and batch.default_workers() == 2
    monkeypatch.setenv("CLISP_DEVICE", "cpu")
    assert batch.local_gpus() == [] and batch.default_workers() == batch.host_cpus()
    monkeypatch.setenv("CLISP_DEVICE", "1")
    assert batch.local_gpus() == []
    monkeypatch.setenv("CLISP_DEVICE", "0:1")
    assert batch.local_gpus() == ["0:1"]
    monkeypatch.setattr(runtime, "list_devices", lambda: [found[2]])
    monkeypatch.delenv("CLISP_DEVICE")
    assert batch.local_gpus() == []

    seen = []
    monkeypatch.setattr(batch, "get_runtime", lambda: seen.append(os.environ["CLISP_DEVICE"]) or
                        SimpleNamespace(describe=lambda: "fake"))
    plugin = batch.RuntimePlugin(["0:0", "0:1"])
    for name in (0, 1, 2):
        plugin.setup(SimpleNamespace(name=name))
    assert seen == ["0:0", "0:1", "0:0"]
