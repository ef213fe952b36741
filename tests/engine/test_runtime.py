"""The OpenCL runtime: device choice, build errors, program cache, buffer pool, transfers."""
from __future__ import annotations

import numpy as np
import pytest

from clisp.errors import ClispError
from clisp.engine.runtime import Runtime, choose_device, get_runtime, list_devices
from conftest import needs_cpu_device


@pytest.fixture(scope="module")
def cl():
    import pyopencl
    return pyopencl


@pytest.fixture(scope="module")
def rt():
    return get_runtime()


# ------------------------------------------------------------------------------------------
# device choice
# ------------------------------------------------------------------------------------------

def test_list_devices_not_empty():
    found = list_devices()
    assert found
    for pi, di, platform, device in found:
        assert isinstance(pi, int) and isinstance(di, int)
        assert device in platform.get_devices()


@pytest.mark.parametrize("spec", ["no-such-device-xyzzy", "99", "0:99"])
def test_choose_device_unknown_spec_lists_devices(spec):
    with pytest.raises(ClispError) as info:
        choose_device(spec)
    message = str(info.value)
    assert repr(spec) in message
    assert "available" in message
    for pi, di, platform, device in list_devices():
        assert f"{pi}:{di}" in message
        assert device.name in message and platform.name in message


@pytest.mark.parametrize("spec", ["0:", ":0"])
def test_choose_device_malformed_index_raises_clisp_error(spec):
    with pytest.raises(ClispError):
        choose_device(spec)


@needs_cpu_device
def test_choose_device_cpu(cl):
    platform, device = choose_device("cpu")
    assert device.type & cl.device_type.CPU
    assert device in platform.get_devices()


def test_choose_device_by_index_and_name():
    pi, di, platform, device = list_devices()[0]
    assert choose_device(f"{pi}:{di}") == (platform, device)
    assert choose_device(str(pi))[0] == platform
    key = device.name.strip().split()[0]
    chosen_platform, chosen = choose_device(key.upper())       # case-insensitive substring
    assert key.lower() in chosen.name.lower() or key.lower() in chosen_platform.name.lower()


def test_choose_device_default():
    platform, device = choose_device(None)
    assert (platform, device) == choose_device("")
    assert any(device == d for _, _, _, d in list_devices())


@needs_cpu_device
def test_runtime_reads_clisp_device(monkeypatch, cl):
    monkeypatch.setenv("CLISP_DEVICE", "no-such-device-xyzzy")
    with pytest.raises(ClispError, match="no-such-device-xyzzy"):
        Runtime()
    assert Runtime("cpu").device.type & cl.device_type.CPU      # an explicit spec wins over the env
    monkeypatch.setenv("CLISP_DEVICE", "cpu")
    assert Runtime().device.type & cl.device_type.CPU


# ------------------------------------------------------------------------------------------
# programs
# ------------------------------------------------------------------------------------------

@needs_cpu_device
def test_build_failure_names_file_and_log():
    fresh = Runtime("cpu")
    defines = {"CFA_PERIOD": 2, "NOUT": 3, "RADIUS": 1, "RAW_T": "float", "PHASE_Y": 0, "PHASE_X": 0,
               "ENCODE_SRGB": 0, "INTERLEAVED": 0}
    with pytest.raises(ClispError) as info:
        fresh.program("linear_filter", defines, generated="this is not C;")
    message = str(info.value)
    assert "linear_filter.cl" in message
    assert "error" in message.lower()
    assert "'this'" in message                       # the compiler's own diagnostic about our text
    assert len(message.splitlines()) > 2
    # a failed build is not cached: the same key fails again, not with a stale program
    with pytest.raises(ClispError):
        fresh.program("linear_filter", defines, generated="this is not C;")


def test_missing_kernel_file():
    with pytest.raises(ClispError, match="no_such_kernel.cl"):
        get_runtime().program("no_such_kernel", {})


def test_program_cache(rt):
    a = rt.program("raw_scale", {"RAW_T": "float", "CFA_PERIOD": 4})
    b = rt.program("raw_scale", {"CFA_PERIOD": 4, "RAW_T": "float"})      # same defines, other order
    assert a is b
    c = rt.program("raw_scale", {"RAW_T": "ushort", "CFA_PERIOD": 4})
    assert c is not a
    d = rt.program("raw_scale", {"RAW_T": "float", "CFA_PERIOD": 4}, generated="/* other */")
    assert d is not a
    assert rt.program("raw_scale", {"RAW_T": "float", "CFA_PERIOD": 4}) is a
    k1 = rt.kernel("raw_scale", "cfa_affine", {"RAW_T": "float", "CFA_PERIOD": 4})
    assert rt.kernel("raw_scale", "cfa_affine", {"CFA_PERIOD": 4, "RAW_T": "float"}) is k1


class _Terminal(list):
    """A stream that says it is a terminal and keeps what is written."""

    def isatty(self) -> bool:
        return True

    def write(self, text: str) -> int:
        self.append(text)
        return len(text)

    def flush(self) -> None:
        pass


def new_runtime(cheap_binaries: bool) -> Runtime:
    """A fresh runtime keeping its programs as a driver whose binaries are cheap does (NVIDIA's: at
    once, after each build) or as PoCL does (when the command ends: Programs.cheap_binaries)."""
    runtime = Runtime()
    runtime.programs.cheap_binaries = cheap_binaries
    return runtime


def records(folder) -> int:
    """How many program records the cache folder ``folder`` holds."""
    return len(list((folder / "programs").iterdir())) if (folder / "programs").exists() else 0


@pytest.mark.parametrize("cheap", [False, True], ids=["kept-at-exit", "kept-at-once"])
def test_first_build_notice_once_per_machine(tmp_path, monkeypatch, cheap):
    """A program this cache has not seen built prints the notice once per runtime; the record it
    keeps (at once where the driver's binaries are cheap, else when the runtime saves its programs,
    as the CLI does when a command ends) keeps the next process (a fresh runtime) quiet; a pipe
    (not a terminal) never gets it."""
    import uuid
    monkeypatch.setenv("CLISP_CACHE_DIR", str(tmp_path))
    first = new_runtime(cheap)
    stream = _Terminal()
    first.programs.notice_stream = stream
    tag = uuid.uuid4().hex
    defines = {"RAW_T": "float", "CFA_PERIOD": 4}
    first.program("raw_scale", defines, generated=f"/* {tag} a */")
    first.program("raw_scale", defines, generated=f"/* {tag} b */")
    text = "".join(stream)
    assert text.count("compiling OpenCL kernels") == 1 and first.device.name.strip() in text
    assert records(tmp_path) == (2 if cheap else 0)
    assert first.save_programs() == (0 if cheap else 2) and records(tmp_path) == 2
    fresh = new_runtime(cheap)
    quiet = _Terminal()
    fresh.programs.notice_stream = quiet
    fresh.program("raw_scale", defines, generated=f"/* {tag} a */")
    assert not quiet
    fresh.program("raw_scale", defines, generated=f"/* {tag} c */")
    assert "".join(quiet).count("compiling") == 1
    piped = new_runtime(cheap)
    piped.program("raw_scale", defines, generated=f"/* {tag} d */")     # sys.stderr: captured, not a tty
    assert not piped.programs.noticed
    closed = _Terminal()
    closed.isatty = lambda: (_ for _ in ()).throw(ValueError("I/O operation on closed file."))
    piped.programs.notice_stream = closed
    piped.program("raw_scale", defines, generated=f"/* {tag} e */")     # a closed stream: no notice, no error
    assert not piped.programs.noticed and not closed


def _scale_twice(runtime: Runtime, tag: str) -> np.ndarray:
    """A tiny program of our own (generated text only, tagged so no cache has it) run on 0..7."""
    source = (f"/* {tag} */\n__kernel void twice(__global const float *src, __global float *dst, const float k)"
              "\n{ const int i = get_global_id(0); dst[i] = k * src[i]; }\n")
    src = runtime.upload(np.arange(8, dtype=np.float32).reshape(1, 8))
    dst = runtime.acquire(1, 1, 8)
    params = runtime.signature("layout", "twice", {"NCH": 1}, source)
    assert [p.name for p in params] == ["src", "dst", "k"] and [p.pointer for p in params] == [True, True, False]
    runtime.kernel("layout", "twice", {"NCH": 1}, source)(runtime.queue, (8,), None, src.buffer, dst.buffer,
                                                    np.float32(2.0))
    return runtime.download(dst).ravel()


@pytest.mark.parametrize("cheap", [False, True], ids=["kept-at-exit", "kept-at-once"])
def test_program_binary_kept_and_loaded(tmp_path, monkeypatch, cheap):
    """A program compiled here is kept as a record (binary and kernel parameters; at once where the
    driver's binaries are cheap, else by save_programs); a later runtime loads it instead of
    compiling (no notice) and its kernels run the same, their parameters known without asking the
    driver; a damaged record is rebuilt from source and kept again, not an error."""
    import uuid
    from clisp.engine import program_store
    monkeypatch.setenv("CLISP_CACHE_DIR", str(tmp_path))
    tag = uuid.uuid4().hex
    first = new_runtime(cheap)
    first.programs.notice_stream = None
    expected = np.arange(8, dtype=np.float32) * 2
    assert np.array_equal(_scale_twice(first, tag), expected)
    assert records(tmp_path) == (1 if cheap else 0)
    assert first.save_programs() == (0 if cheap else 1)
    (record,) = (tmp_path / "programs").iterdir()
    binary, kernels = program_store.read_record(record)
    assert binary and [p[0] for p in kernels["twice"]] == ["src", "dst", "k"]
    later = new_runtime(cheap)
    stream = _Terminal()
    later.programs.notice_stream = stream
    assert np.array_equal(_scale_twice(later, tag), expected)
    assert not stream and later.save_programs() == 0                  # loaded: nothing to keep
    record.write_bytes(record.read_bytes()[:100])                      # damaged
    assert program_store.read_record(record) is None
    again = new_runtime(cheap)
    again.programs.notice_stream = None
    assert np.array_equal(_scale_twice(again, tag), expected) and again.save_programs() == (0 if cheap else 1)
    assert program_store.read_record(record) is not None                # kept again, whole


def test_metering_builds_its_programs_at_once(tmp_path, monkeypatch):
    """Programs a metering run asks for are noted, not built, inside it, and built when it ends (on
    PoCL shared out with helper processes, whose records this process then loads): every one is then
    built, kept on disk and runs."""
    import uuid
    from clisp.engine import programs
    monkeypatch.setenv("CLISP_CACHE_DIR", str(tmp_path))
    tags = [uuid.uuid4().hex for _ in range(3)]

    def metered(runtime: Runtime) -> None:
        """A metering run asking for the three programs: none built inside it, all three after."""
        runtime.programs.notice_stream = None
        with runtime.metering():
            for tag in tags:
                runtime.launch_named("raw_scale", "cfa_affine", 8, 4, {}, {"RAW_T": "float", "CFA_PERIOD": 4},
                                     generated=f"/* {tag} */")
            assert not runtime.programs.built
        assert len(runtime.programs.built) == 3
    fresh = Runtime()
    metered(fresh)
    if not fresh.programs.cheap_binaries and programs._usable_cores() > 1:    # built in parallel: kept at once
        assert len(list((tmp_path / "programs").iterdir())) == 3
    fresh.save_programs()
    assert len(list((tmp_path / "programs").iterdir())) == 3
    for tag in tags:
        params = fresh.signature("raw_scale", "cfa_affine", {"RAW_T": "float", "CFA_PERIOD": 4}, f"/* {tag} */")
        assert params and params[0].pointer
    later = Runtime()                                   # the records kept: loaded together at the end, none built
    monkeypatch.setattr(later.programs, "_build", lambda *a: pytest.fail("a kept program was built again"))
    metered(later)


def test_warm_builds_what_a_run_needs(tmp_path):
    """After warming a preset for a CFA kind, processing another raw of that kind with that preset
    (other gain, size and content; read from its file as the CLI does, and from an aligned copy in
    memory in several tiles, where the device gathers the windows) builds no program the warm-up
    did not."""
    from dataclasses import replace
    from clisp.io.rawfile import read_raw, write_raw
    from clisp.pipeline import process_file
    from clisp.sim.charts import dead_leaves
    from clisp.sim.simulate import simulate
    from clisp.app.warm import aligned, warm_kernels

    rt = get_runtime()
    warm_kernels(("quality",), ("bayer",), report=None)
    built = set(rt.programs.built)
    scene = dead_leaves(128, seed=2)
    scene[:24, :24] = 3.0
    write_raw(tmp_path / "r.dng", simulate(scene[:, :112], "bayer", gain=16, seed=3).raw)
    raw = read_raw(tmp_path / "r.dng", lazy=True)
    process_file(raw, tmp_path / "x.tif", preset="quality", skip=True)
    process_file(replace(raw, data=aligned(raw.data)), tmp_path / "x.tif", tile=64, preset="quality", skip=True)
    assert set(rt.programs.built) == built


# ------------------------------------------------------------------------------------------
# buffers and transfers
# ------------------------------------------------------------------------------------------

@needs_cpu_device
def test_buffer_pool_reuses_released_buffers():
    fresh = Runtime("cpu")
    a = fresh.acquire(3, 17, 19)
    assert a.nbytes == 3 * 17 * 19 * 4 and a.dtype == np.float32
    b = fresh.acquire(3, 17, 19)
    assert b.buffer is not a.buffer                   # both in use: distinct buffers
    fresh.release(a)
    c = fresh.acquire(3, 17, 19)
    assert c.buffer is a.buffer                       # released buffer handed out again
    d = fresh.acquire(3, 17, 20)
    assert d.buffer is not b.buffer and d.buffer is not a.buffer   # other size: new buffer
    fresh.release(b)
    e = fresh.upload(np.zeros((3, 17, 19), np.float32))
    assert e.buffer is not b.buffer and not e.pooled  # on a CPU device an upload is a buffer of its own
    fresh.release(e)
    assert fresh.acquire(3, 17, 19).buffer is b.buffer   # and is not pooled when released


UPLOAD_BEHIND_A_HELD_QUEUE = """
import numpy as np
from clisp.engine.runtime import Runtime
rt = Runtime("cpu")
gate = rt.cl.UserEvent(rt.context)
rt.cl.enqueue_marker(rt.queue, wait_for=[gate])
image = rt.upload(np.arange(12, dtype=np.float32).reshape(3, 4))
print("returned", flush=True)
gate.set_status(rt.cl.command_execution_status.COMPLETE)
rt.finish()
assert (rt.download(image) == np.arange(12, dtype=np.float32).reshape(3, 4)).all()
"""


@needs_cpu_device
def test_an_upload_does_not_wait_for_the_commands_queued_before_it():
    """On a CPU device (PoCL) a write into a buffer waits until every command queued before it has
    run, holding the GIL (no other thread of the process runs meanwhile); Runtime.upload makes a
    buffer from the array instead. A child process holds its queue with a marker waiting on a
    user event and uploads: the upload must return while the queue is held (the child would wait
    forever; its 60 s limit only stops that, no time is measured)."""
    import subprocess
    import sys
    try:
        child = subprocess.run([sys.executable, "-c", UPLOAD_BEHIND_A_HELD_QUEUE], capture_output=True, text=True,
                               timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("Runtime.upload waited for the commands queued before it")
    assert child.returncode == 0 and "returned" in child.stdout, child.stderr


def test_constant_cache(rt):
    a = rt.constant(np.array([1.0, 2.0, 3.0], np.float32))
    assert rt.constant(np.array([1.0, 2.0, 3.0], np.float32)) is a
    assert rt.constant(np.array([1.0, 2.0, 4.0], np.float32)) is not a
    assert rt.constant(np.array([1, 2, 3], np.int8)) is not a


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_upload_download_roundtrip(rt, dtype):
    x = (np.random.default_rng(1).random((13, 29)) * 1000).astype(dtype)
    image = rt.upload(x)
    assert (image.channels, image.height, image.width, image.dtype) == (1, 13, 29, np.dtype(dtype))
    np.testing.assert_array_equal(rt.download(image), x)
    into = np.empty((13, 29), dtype)
    assert rt.download(image, into=into) is into
    np.testing.assert_array_equal(into, x)
    with pytest.raises(ValueError):
        rt.download(image, into=np.empty((29, 13), dtype))
    rt.release(image)


def test_interleave(rt):
    planar = np.random.default_rng(2).random((3, 11, 37)).astype(np.float32)
    image = rt.upload(planar)
    np.testing.assert_array_equal(rt.download(image), planar)
    inter = rt.interleave(image)
    assert inter.interleaved and inter.channels == 3
    np.testing.assert_array_equal(rt.download(inter), np.moveaxis(planar, 0, -1))
    rt.release(image)
    rt.release(inter)


def test_upload_infers_channels_of_planar_array(rt):
    planar = np.arange(3 * 5 * 7, dtype=np.float32).reshape(3, 5, 7)
    image = rt.upload(planar)
    assert image.channels == 3
    np.testing.assert_array_equal(rt.download(image), planar)


def test_launch_named_orders_checks_and_converts_arguments(rt):
    """A launch by name: arguments in any order, scalars converted to the declared types, a
    DeviceImage passed as its buffer; the result equals the positional launch (interleave). A
    missing or unknown name is refused, naming it, before anything runs."""
    planar = np.arange(3 * 5 * 7, dtype=np.float32).reshape(3, 5, 7)
    src = rt.upload(planar)
    dst = rt.acquire(3, 5, 7)
    rt.launch_named("layout", "interleave", 7, 5, dict(height=5, width=7.0, dst=dst, src=src), {"NCH": 3},
                    exact=False)
    dst.interleaved = True
    np.testing.assert_array_equal(rt.download(dst), rt.download(rt.interleave(src)))
    assert [(p.name, p.type_name, p.pointer) for p in rt.signature("layout", "interleave", {"NCH": 3})] == [
        ("src", "float*", True), ("dst", "float*", True), ("width", "int", False), ("height", "int", False)]
    with pytest.raises(ClispError, match=r"missing arguments \['height'\], unknown \['hieght'\]"):
        rt.launch_named("layout", "interleave", 7, 5, dict(src=src, dst=dst, width=7, hieght=5), {"NCH": 3})


INWARD_PROBE = """
__kernel void probe(__global int *out, const int w, const int h)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    atomic_inc(&out[w * h + y * w + x]);                /* how many work-items reached (y, x) */
    out[y * w + x] = y * w + x + 1;
}
"""


@pytest.mark.parametrize("w, h", [(1, 1), (3, 5), (64, 4), (65, 5), (130, 9), (200, 3), (127, 130)])
def test_an_inward_launch_is_one_command_writing_every_output_and_nothing_past_it(rt, w, h):
    """launch_exact(inward=True) with common.h's inward_id: one command over whole work-groups; every
    output is written with its own value, the last work-group's ids stay inside (it recomputes
    outputs of the group before: those are reached twice per axis, the rest once), nothing past w x h is
    touched, and the work-items reached are exactly the rounded-up launch."""
    import pyopencl as cl
    from clisp.engine.programs import kernel_path
    from clisp.engine.runtime import WORK_GROUP, launch_exact
    program = cl.Program(rt.context, kernel_path("common.h").read_text() + INWARD_PROBE).build()
    kernel = program.probe
    kernel.set_scalar_arg_dtypes([None, np.int32, np.int32])
    guard = 64
    out = np.zeros(2 * w * h + guard, np.int32)
    buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=out)
    commands = []

    def counted(*args, **kwargs):
        commands.append(args[1])
        return kernel(*args, **kwargs)

    launch_exact(rt, counted, w, h, buf, w, h, inward=True)
    assert len(commands) == 1
    cl.enqueue_copy(rt.queue, out, buf)
    np.testing.assert_array_equal(out[:w * h], np.arange(1, w * h + 1))
    reached = out[w * h:2 * w * h].reshape(h, w)
    assert reached.min() >= 1 and reached.max() <= 4 and not out[2 * w * h:].any()   # twice per axis at most
    lx, ly = (min(g, 1 << (n.bit_length() - 1)) for g, n in zip(WORK_GROUP, (w, h)))
    assert reached.sum() == -(-w // lx) * lx * -(-h // ly) * ly


@pytest.mark.parametrize("helper", ["/nonexistent/python", "/bin/false"])
def test_parallel_build_survives_a_helper_that_fails(tmp_path, monkeypatch, helper):
    """A helper that cannot start, or exits without building, costs only time: the runtime builds
    what it left out, and every program runs."""
    import sys
    import uuid
    from clisp.engine import programs
    monkeypatch.setenv("CLISP_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(sys, "executable", helper)
    monkeypatch.setattr(programs, "_usable_cores", lambda: 4)         # helpers even on a 1-core machine
    fresh = Runtime()
    fresh.programs.notice_stream = None
    fresh.programs.cheap_binaries = False                             # the parallel path, whatever the driver
    defines = {"RAW_T": "float", "CFA_PERIOD": 4}
    tags = [uuid.uuid4().hex for _ in range(3)]
    with fresh.metering():
        for tag in tags:
            fresh.launch_named("raw_scale", "cfa_affine", 8, 4, {}, defines, generated=f"/* {tag} */")
    assert len(fresh.programs.built) == 3
    for tag in tags:
        assert fresh.signature("raw_scale", "cfa_affine", defines, f"/* {tag} */")[0].pointer
