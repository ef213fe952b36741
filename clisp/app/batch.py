"""Batches of raws on Dask (``clisp batch``): parallel, failure-isolated, resumable, with a manifest.

The client (this process) plans one job per input, skips the jobs a previous run finished with
the same settings, and submits the rest to a Dask ``distributed`` cluster: by default a local one
of worker *processes* (one OpenCL context each: PoCL contexts and queues are per process), or an
existing cluster at ``--scheduler ADDRESS``. Each worker builds its OpenCL context once, when it
joins (:class:`RuntimePlugin`); programs stay cached in that process for the following files.

Every result is appended to ``OUTDIR/manifest.jsonl`` as it arrives (one JSON object per file and
attempt; written by the client alone, flushed and fsynced line by line), so a killed batch loses
nothing it finished: outputs are written under a temporary name and renamed when complete
(clisp.io.imageio.atomic_path), and a re-run skips every output whose manifest record has the same
settings hash, the same input (size, mtime) and whose file still has the recorded size and
SHA-256 (:func:`is_finished`). A file that fails becomes an ``error`` record with a one-line
message naming it; the others go on.

The same machinery runs arbitrary per-item work (simulation sweeps, tools/reproduce_paper.py):
:func:`dask_client` and :func:`map_ordered`.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import logging
import os
import sys
import time
import uuid
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

from ..version import __version__
from ..errors import ClispError
from ..engine.runtime import DEVICE_LOCK, get_runtime, save_built_programs
from ..io.rawfile import RAW_SUFFIXES, read_raw
from ..pipeline import (DEFAULT_BUDGET, DEFAULT_PRESET, GPU_FILES_IN_FLIGHT, SKIP_WHERE_IT_PAYS, process_file,
                        resolve_options)
# clisp.app.batch is imported by every CLI command (cli._add_batch): Dask, distributed, cloudpickle,
# tqdm and clisp.io.imageio are imported where they are used.

MANIFEST = "manifest.jsonl"
FORMATS = ("exr", "tif", "png", "jpg")
START_TIMEOUT = 60.0
"""Seconds to wait for a cluster to start or a scheduler to answer, and for a first worker."""


# ------------------------------------------------------------------------------------------
# settings and jobs
# ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class BatchSettings:
    """What a batch does to each file. Everything but ``mem`` changes the output and is hashed.

    ``preset``/``demosaic``: as ``clisp process``; ``format``: 'exr', 'tif', 'png' or 'jpg';
    ``compression``: EXR/TIFF/PNG/JPEG compression (None = clisp's default); ``exposure``, ``auto_exposure``,
    ``half_size``: as ``process --exposure``, ``--auto-exposure``, ``--half-size``; ``wb``: as
    ``process --wb``; ``resize``: the long edge, as ``process --resize`` (None: the raw's size);
    ``skip``: as ``process``
    (False = ``--no-skip``: every stage on every tile); ``mem``: peak resident
    memory of each worker's processing in bytes (``process --mem``), not hashed: it changes the
    tiling, not the pixels.
    """
    preset: str | None = None
    format: str = "exr"
    demosaic: str | None = None
    compression: str | None = None
    mem: int | None = None
    skip: bool = True
    exposure: float = 0.0
    auto_exposure: bool = False
    wb: str = "camera"
    resize: int | None = None
    half_size: bool = False

    def identity(self) -> dict[str, Any]:
        """The hashed part: the resolved preset, the options that change an output, clisp's version
        (the exposure, white balance, resize and half size only when set, so that the batches run
        before they existed stay done)."""
        identity = {"clisp": __version__, "preset": self.preset or DEFAULT_PRESET, "demosaic": self.demosaic,
                    "format": self.format, "compression": self.compression, "skip": self.skip}
        if self.exposure:
            identity["exposure"] = self.exposure
        if self.auto_exposure:
            identity["auto_exposure"] = True
        if self.wb != "camera":
            identity["wb"] = self.wb
        if self.resize:
            identity["resize"] = self.resize
        if self.half_size:
            identity["half_size"] = True
        return identity

    def digest(self) -> str:
        """16 hex digits of the SHA-256 of :meth:`identity` (canonical JSON)."""
        text = json.dumps(self.identity(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Job:
    """One input and its output. ``output`` is absolute (workers write it); the manifest stores
    its name in OUTDIR. ``input_size`` (bytes) and ``input_mtime_ns`` identify the input's
    version (None when it cannot be read: the worker then reports why)."""
    input: str
    output: str
    input_size: int | None = None
    input_mtime_ns: int | None = None

    @property
    def name(self) -> str:
        return Path(self.output).name


def collect_inputs(inputs: Iterable[str | Path]) -> list[Path]:
    """Files named, plus the raw files (RAW_SUFFIXES, not hidden) directly inside folders named;
    duplicates (same resolved path) once, in the order given (folders sorted by name)."""
    seen: dict[Path, None] = {}
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            files = sorted(f for f in p.iterdir() if f.is_file() and not f.name.startswith(".")
                           and f.suffix.lower() in RAW_SUFFIXES)
        else:
            files = [p]
        for f in files:
            seen.setdefault(f.resolve(), None)
    return list(seen)


def plan_jobs(inputs: Sequence[Path], outdir: Path, fmt: str) -> list[Job]:
    """One job per input: ``OUTDIR/<input stem>.<fmt>``. ClispError when two inputs share a stem
    (they would write the same output)."""
    if fmt not in FORMATS:
        raise ClispError(f"unknown format {fmt!r}; use {', '.join(FORMATS)}")
    outdir = outdir.resolve()
    by_output: dict[str, Path] = {}
    jobs = []
    for p in inputs:
        out = outdir / f"{p.stem}.{fmt}"
        if str(out) in by_output:
            raise ClispError(f"{p} and {by_output[str(out)]} would both write {out.name}; "
                             "rename one or run them into different folders")
        by_output[str(out)] = p
        try:
            st = p.stat()
            size, mtime = st.st_size, st.st_mtime_ns
        except OSError:
            size = mtime = None
        jobs.append(Job(str(p), str(out), size, mtime))
    return jobs


def file_sha256(path: str | Path, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file, read in ``chunk``-byte pieces."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


# ------------------------------------------------------------------------------------------
# the worker's side
# ------------------------------------------------------------------------------------------

def process_one(job: Job, settings: BatchSettings, digest: str, run: str) -> dict[str, Any]:
    """Process one file (on a worker). Never raises for a bad input: returns its manifest record,
    status 'ok' with the image's width, height and tiles and the output's size, mtime and SHA-256, or 'error' with a one-line message
    naming the file. ``seconds``: wall time of reading, processing, writing and hashing."""
    start = time.perf_counter()
    record = _record(job, "ok", digest, run)
    record["worker"] = _worker_address()
    try:
        raw = read_raw(job.input, lazy=True)
        (height, width), stats = process_file(raw, job.output, budget=settings.mem or DEFAULT_BUDGET,
                                          compression=settings.compression, preset=settings.preset,
                                          demosaic=settings.demosaic, skip=SKIP_WHERE_IT_PAYS if settings.skip else None,
                                          exposure=settings.exposure, auto_exposure=settings.auto_exposure,
                                          wb=settings.wb, resize=settings.resize, half_size=settings.half_size)
        st = os.stat(job.output)
        record.update(width=width, height=height, tiles=stats.tiles, size=st.st_size, mtime_ns=st.st_mtime_ns,
                      sha256=file_sha256(job.output))
    except Exception as exc:  # noqa: BLE001 - one bad file must not stop the batch
        record.update(status="error", error=error_line(job.input, exc))
    with DEVICE_LOCK:              # a worker's compiled programs kept for later processes (nothing new: no cost)
        save_built_programs()
    record["seconds"] = round(time.perf_counter() - start, 4)
    return record


def error_line(path: str, exc: BaseException) -> str:
    """One line naming ``path`` and the problem (ClispError text as is, else the exception type too)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if not isinstance(exc, ClispError):
        text = f"{type(exc).__name__}: {text}"
    return text if path in text or Path(path).name in text else f"{path}: {text}"


def _worker_address() -> str | None:
    try:
        from distributed import get_worker      # deferred: distributed costs 0.2 s of start-up
        return get_worker().address
    except (ImportError, ValueError):
        return None


_CACHE: dict[Any, Any] = {}


def worker_cache(key: Any, factory: Callable[[], Any]) -> Any:
    """``factory()`` once per process and ``key``: state that a worker keeps across tasks (a
    Runner with its noise tables, a test chart), in this importable module so that functions
    shipped by value to workers (tools' code) still find it on the next task."""
    if key not in _CACHE:
        _CACHE[key] = factory()
    return _CACHE[key]


class RuntimePlugin:
    """Dask worker plugin: builds the worker process's OpenCL context (clisp.engine.runtime.get_runtime,
    once per process) when the worker starts, not inside the first file's time. ``gpus``: the
    local cluster's GPUs (local_gpus): worker i takes GPU i modulo their count (CLISP_DEVICE set
    in its process before the context is made)."""

    name = "clisp-runtime"

    def __init__(self, gpus: Sequence[str] = ()) -> None:
        self.gpus = list(gpus)

    def setup(self, worker: Any) -> None:
        if len(self.gpus) > 1:
            try:
                index = int(worker.name)
            except (TypeError, ValueError):
                index = abs(hash(worker.name))
            os.environ["CLISP_DEVICE"] = self.gpus[index % len(self.gpus)]
        worker.clisp_device = get_runtime().describe()

    def teardown(self, worker: Any) -> None:
        pass


def _worker_plugin(gpus: Sequence[str] = ()) -> Any:
    from distributed import WorkerPlugin        # deferred: distributed costs 0.2 s of start-up

    class _Plugin(RuntimePlugin, WorkerPlugin):
        pass
    return _Plugin(gpus)


# ------------------------------------------------------------------------------------------
# the client's side: cluster, manifest, resume
# ------------------------------------------------------------------------------------------

def host_cpus() -> int:
    """The CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def local_gpus() -> list[str]:
    """The GPUs a local cluster's workers run on, as CLISP_DEVICE specs ('P:D'): every GPU OpenCL
    lists when CLISP_DEVICE is unset or 'gpu' (the default device is then a GPU), the one it names
    when that is a GPU; none where the workers' device is a CPU or OpenCL cannot be asked."""
    from ..engine.runtime import choose_device, list_devices    # deferred: pyopencl, 0.1 s
    spec = os.environ.get("CLISP_DEVICE", "").strip()
    try:
        cl = __import__("pyopencl")
        found = list_devices()
        if spec.lower() in ("", "gpu"):
            return [f"{p}:{d}" for p, d, _, device in found if device.type & cl.device_type.GPU]
        platform, device = choose_device(spec)
    except Exception:  # noqa: BLE001 - no OpenCL here (ClispError, ImportError, cl.Error): the workers find out
        return []
    if not device.type & cl.device_type.GPU:
        return []
    return [f"{p}:{d}" for p, d, pl, dev in found if dev == device][:1]


def default_workers() -> int:
    """Worker processes of a local cluster: one per GPU where the workers' device is a GPU (one
    context per GPU: sixteen processes sharing one GPU would each hold its context, programs and
    buffers), else one per CPU this process may run on."""
    return len(local_gpus()) or host_cpus()


def local_worker_env(workers: int) -> dict[str, str]:
    """Environment of a local cluster's workers: PoCL's CPU device gets CPUs / ``workers``
    threads per worker (POCL_CPU_MAX_CU_NUM) rather than a thread per CPU in every worker, unless
    the user set it. (2 workers on 2 CPUs: 1.3x the throughput, tools/bench_batch.py.)"""
    if workers <= 1 or "POCL_CPU_MAX_CU_NUM" in os.environ:
        return {}
    return {"POCL_CPU_MAX_CU_NUM": str(max(1, host_cpus() // workers))}


class _WorkersCannotRun(Exception):
    """Setting a worker up failed there (clisp missing or broken on it)."""


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None,
                timeout: float = START_TIMEOUT, worker_env: dict[str, str] | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: on the cluster at ``scheduler`` (an address such as
    tcp://host:8786), else on a new local cluster on loopback, closed on exit, of ``workers``
    processes (default: one per GPU where the workers' device is a GPU, local_gpus, each with
    GPU_FILES_IN_FLIGHT threads whose files overlap; else one per CPU, one thread each). Each worker builds its OpenCL context
    once (:class:`RuntimePlugin`). ``timeout``: seconds for start-up and for a first worker
    (ClispError past it). ``worker_env``: environment of local workers (default
    :func:`local_worker_env`)."""
    import dask                                  # deferred: dask costs 0.1 s, distributed 0.2 s of start-up
    try:
        from distributed import Client, LocalCluster     # deferred: an optional dependency, 0.2 s of start-up
    except ImportError as exc:
        raise ClispError("clisp batch needs Dask: pip install 'dask[distributed]'") from exc
    cluster = client = None
    gpus: list[str] = []
    config = {"distributed.comm.timeouts.connect": f"{timeout}s",
              "distributed.scheduler.allowed-failures": 1}   # a file that kills a worker is retried once
    try:
        with dask.config.set(config), warnings.catch_warnings():
            if scheduler:
                client = Client(scheduler, timeout=timeout)
            else:
                gpus = local_gpus()
                n = workers or len(gpus) or host_cpus()
                warnings.filterwarnings("ignore", message="Port .* is already in use")   # a free one is taken
                cluster = LocalCluster(n_workers=n, threads_per_worker=GPU_FILES_IN_FLIGHT if gpus else 1,
                                       processes=True, host="127.0.0.1", dashboard_address=None,
                                       silence_logs=logging.ERROR,
                                       env=({} if gpus else local_worker_env(n)) if worker_env is None
                                       else dict(worker_env))
                client = Client(cluster, timeout=timeout)
            client.wait_for_workers(1, timeout=timeout)
            try:
                client.register_plugin(_worker_plugin(gpus))
            except Exception as exc:  # noqa: BLE001 - the workers' own error, e.g. no clisp there
                raise _WorkersCannotRun(" ".join(str(exc).split())) from exc
    except (OSError, TimeoutError, _WorkersCannotRun) as exc:
        for c in (client, cluster):
            if c is not None:
                c.close()
        where = f"scheduler {scheduler}" if scheduler else "a local Dask cluster"
        if isinstance(exc, _WorkersCannotRun):
            raise ClispError(f"the workers of {where} cannot run clisp ({exc}); install this clisp "
                             f"({__version__}) where they run") from exc
        raise ClispError(f"cannot start {where} within {timeout:g} s: {' '.join(str(exc).split())}") from exc
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def map_ordered(client: Any | None, fn: Callable[..., Any], items: Sequence[Any], *args: Any,
                progress: str | None = None, timeout: float | None = None) -> list[Any]:
    """``[fn(item, *args) for item in items]``, on the Dask cluster of ``client`` (in parallel,
    results in the order of ``items``) or in this process when ``client`` is None. An item's
    exception is raised here; so is TimeoutError when the results take longer than ``timeout``
    seconds (None: no limit). ``fn`` and ``args`` travel by cloudpickle, so modules registered
    with ``cloudpickle.register_pickle_by_value`` (tools/ scripts the workers cannot import)
    reach the workers by value. ``progress``: label of a progress bar (on a terminal)."""
    bar = _progress(len(items), progress)
    try:
        if client is None:
            out = []
            for item in items:
                out.append(fn(item, *args))
                bar.update(1)
            return out
        import cloudpickle                       # deferred: only the Dask path pickles
        from distributed import as_completed     # deferred: 0.2 s of start-up
        blob = cloudpickle.dumps((fn, args))
        futures = [client.submit(_call_pickled, blob, item, pure=False) for item in items]
        for _ in as_completed(futures, timeout=timeout):
            bar.update(1)
        return client.gather(futures)
    finally:
        bar.close()


def _call_pickled(blob: bytes, item: Any) -> Any:
    """On a worker: ``fn(item, *args)`` for ``(fn, args)`` cloudpickled in ``blob`` (unpickled
    once per process)."""
    import cloudpickle                           # deferred: only the Dask path pickles
    fn, args = worker_cache(("pickled", hashlib.sha1(blob).hexdigest()), lambda: cloudpickle.loads(blob))
    return fn(item, *args)


def _progress(total: int, label: str | None) -> Any:
    from tqdm import tqdm                        # deferred: tqdm costs 20 ms of start-up
    return tqdm(total=total, desc=label, unit="file", disable=label is None or not sys.stderr.isatty(),
                leave=False, dynamic_ncols=True)


class Manifest:
    """``OUTDIR/manifest.jsonl``, appended one line per record (flushed and fsynced), and locked
    (flock) while a batch runs, so that two batches never write one folder."""

    def __init__(self, outdir: Path) -> None:
        self.path = outdir / MANIFEST
        self.records = read_manifest(self.path)
        self._file = open(self.path, "a", encoding="utf-8")
        try:
            fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            self._file.close()
            raise ClispError(f"{self.path}: another clisp batch is writing this folder") from exc

    def append(self, record: dict[str, Any]) -> None:
        self._file.write(json.dumps(record, sort_keys=False) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


def read_manifest(path: Path) -> list[dict[str, Any]]:
    """The records of a manifest, oldest first; a torn last line (a killed write) is ignored."""
    if not path.exists():
        return []
    records = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(record, dict):
                records.append(record)
    return records


def last_ok(records: Iterable[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The latest 'ok' record of each output name."""
    return {r["output"]: r for r in records if r.get("status") == "ok" and "output" in r}


def is_finished(job: Job, record: dict[str, Any] | None, digest: str, outdir: Path) -> bool:
    """Whether ``record`` (the output's last 'ok') still stands: same settings hash, same input
    (path, size, mtime), and the output file complete: its size as recorded, and its SHA-256 as
    recorded (re-hashed only when its mtime changed since)."""
    if record is None or record.get("settings") != digest or record.get("input") != job.input:
        return False
    if (record.get("input_size"), record.get("input_mtime_ns")) != (job.input_size, job.input_mtime_ns):
        return False
    try:
        st = os.stat(outdir / job.name)
    except OSError:
        return False
    if st.st_size != record.get("size"):
        return False
    return st.st_mtime_ns == record.get("mtime_ns") or file_sha256(outdir / job.name) == record.get("sha256")


def _record(job: Job, status: str, digest: str, run: str) -> dict[str, Any]:
    return {"input": job.input, "output": job.name, "status": status, "error": None, "seconds": 0.0,
            "settings": digest, "worker": None, "run": run, "input_size": job.input_size,
            "input_mtime_ns": job.input_mtime_ns}


def _remove_partials(outdir: Path, jobs: Iterable[Job]) -> int:
    """Remove temporary files a killed run left for these outputs (clisp.io.imageio.atomic_path's
    ``.<stem>.partial-*<suffix>``); the manifest lock says no batch is writing them. Returns the count."""
    count = 0
    for job in jobs:
        out = Path(job.output)
        for tmp in outdir.glob(f".{out.stem}.partial-*{out.suffix}"):
            tmp.unlink(missing_ok=True)
            count += 1
    return count


# ------------------------------------------------------------------------------------------
# the batch
# ------------------------------------------------------------------------------------------

@dataclass
class BatchSummary:
    """Counts of a batch run; ``seconds``: wall time from submitting to the last result;
    ``megapixels``: of the files processed ok in this run; ``workers``: addresses that ran files."""
    ok: int = 0
    errors: int = 0
    skipped: int = 0
    seconds: float = 0.0
    megapixels: float = 0.0
    workers: set[str] = field(default_factory=set)
    manifest: str = ""
    failed: list[str] = field(default_factory=list)

    @property
    def total(self) -> int:
        return self.ok + self.errors + self.skipped


def run_batch(inputs: Sequence[str | Path], outdir: str | Path, settings: BatchSettings,
              workers: int | None = None, scheduler: str | None = None, progress: bool = False,
              timeout: float | None = None, start_timeout: float = START_TIMEOUT,
              worker_env: dict[str, str] | None = None,
              on_record: Callable[[dict[str, Any]], None] | None = None) -> BatchSummary:
    """Process ``inputs`` (files or folders of raws) into ``outdir`` on Dask; see the module doc.

    ``workers``/``scheduler``/``start_timeout``/``worker_env``: :func:`dask_client`.
    ``timeout``: seconds to wait for all results (None = no limit); past it the files still
    running are recorded as errors. ``on_record``: called with each manifest record as written.
    """
    from ..io.imageio import check_compression    # deferred: 2 ms of every CLI command's start-up
    resolve_options(settings.preset, settings.demosaic, half_size=settings.half_size)   # bad names fail before anything runs
    outdir = Path(outdir)
    if settings.compression:
        check_compression(f"x.{settings.format}", settings.compression)
    files = collect_inputs(inputs)
    if not files:
        raise ClispError("no input files (folders are searched for raw files: "
                         f"{', '.join(sorted(RAW_SUFFIXES))})")
    jobs = plan_jobs(files, outdir, settings.format)
    outdir.mkdir(parents=True, exist_ok=True)
    digest, run = settings.digest(), time.strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:6]
    manifest = Manifest(outdir)
    summary = BatchSummary(manifest=str(manifest.path))

    def write(record: dict[str, Any]) -> None:
        manifest.append(record)
        status = record["status"]
        if status == "ok":
            summary.ok += 1
            summary.megapixels += record.get("width", 0) * record.get("height", 0) / 1e6
        elif status == "skipped":
            summary.skipped += 1
        else:
            summary.errors += 1
            summary.failed.append(record["error"])
        if record.get("worker"):
            summary.workers.add(record["worker"])
        if on_record is not None:
            on_record(record)

    try:
        previous = last_ok(manifest.records)
        todo = []
        for job in jobs:
            if is_finished(job, previous.get(job.name), digest, outdir):
                record = _record(job, "skipped", digest, run)
                for key in ("width", "height", "size", "mtime_ns", "sha256"):
                    record[key] = previous[job.name].get(key)
                write(record)
            else:
                todo.append(job)
        _remove_partials(outdir, todo)
        if todo:
            with dask_client(workers, scheduler, start_timeout, worker_env) as client:
                start = time.perf_counter()
                _run_jobs(client, todo, settings, digest, run, write, progress, timeout)
                summary.seconds = time.perf_counter() - start
    finally:
        manifest.close()
    return summary


def _run_jobs(client: Any, jobs: list[Job], settings: BatchSettings, digest: str, run: str,
              write: Callable[[dict[str, Any]], None], progress: bool, timeout: float | None) -> None:
    """Submit every job, write each record as its result arrives; a worker's death or the
    ``timeout`` become error records of the files concerned."""
    from distributed import as_completed         # deferred: 0.2 s of start-up
    futures = {client.submit(process_one, job, settings, digest, run, pure=False,
                             key=f"clisp-batch-{job.name}-{uuid.uuid4().hex[:8]}"): job for job in jobs}
    bar = _progress(len(jobs), "clisp batch" if progress else None)
    done: set[Any] = set()
    try:
        for future in as_completed(futures, timeout=timeout):
            job = futures[future]
            done.add(future)
            try:
                record = future.result()
            except Exception as exc:  # noqa: BLE001 - a worker died on it (KilledWorker) or similar
                record = _record(job, "error", digest, run)
                record["error"] = error_line(job.input, exc) + " (the worker processing it failed)"
            write(record)
            bar.update(1)
    except TimeoutError:
        for future, job in futures.items():
            if future not in done:
                future.cancel()
                record = _record(job, "error", digest, run)
                record["error"] = f"{job.input}: no result within the batch timeout of {timeout:g} s"
                write(record)
    finally:
        bar.close()


def summary_line(summary: BatchSummary) -> str:
    """One line: counts, time, throughput (files/s and MP/s of the files processed) and workers."""
    done = summary.ok + summary.errors
    rate = (f"{done / summary.seconds:.2f} files/s, {summary.megapixels / summary.seconds:.2f} MP/s"
            if summary.seconds > 0 and done else "nothing to process")
    return (f"{summary.ok} ok, {summary.errors} failed, {summary.skipped} skipped (finished before) "
            f"in {summary.seconds:.1f} s ({rate}) on {len(summary.workers)} worker(s); "
            f"manifest {summary.manifest}")


__all__ = ["BatchSettings", "BatchSummary", "Job", "run_batch", "process_one", "dask_client", "map_ordered", "worker_cache",
           "read_manifest", "is_finished", "summary_line"]
