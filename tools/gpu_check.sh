#!/usr/bin/env bash
# The GPU figures of issue 41 in one run on a lent GPU machine (NVIDIA's OpenCL), in about 5 minutes.
#
#   tools/gpu_check.sh --prepare     here, on a machine with pip's index (no GPU needed):
#       .whl/              wheels the GPU machine's image lacks, for its Python (3.12): pyopencl,
#                          rawpy, OpenImageIO, colour-science, exiv2 and what they need
#       .gpu/base/         the tree before issue 41 (BASE, its parent commit), as a git worktree
#       .gpu/cpu_stats.json  this machine's statistics of every preset's 1 MP outputs
#                          (tools/bench_device.py stats), which the GPU's are compared with
#   both folders are ignored by git (.git/info/exclude); together about 40 MB.
#
#   device tool: run(command="bash tools/gpu_check.sh", carry=[".whl", ".gpu"], timeout_s=600)
#       on the GPU machine: installs the wheels into /tmp/site, checks the driver's OpenCL library
#       first, then runs the kernel tests with CLISP_DEVICE=gpu, the in-process throughput of this
#       tree and BASE's (tools/bench_device.py throughput), the whole process against rawpy on a
#       24 MP Bayer DNG simulated there, 20 such raws through one `clisp process`, and the outputs'
#       statistics against the CPU's; prints one table at the end. Logs and JSON go to $OUT.
#   QUICK=1: a first look instead (no tests or statistics): the throughput, the whole process and
#       where it goes (cProfile), about 2 minutes.
#
# Nothing here is timed in a test: these are benchmarks (docs/RESULTS.md, issue 41).
set -u
BASE=${BASE:-84a7a13}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"

if [ "${1:-}" = "--prepare" ]; then
    set -e
    grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
    grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo '/.gpu/' >> .git/info/exclude
    mkdir -p .whl .gpu
    for pkg in pyopencl pytools platformdirs siphash24 rawpy OpenImageIO colour-science exiv2; do
        python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
            --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
            --platform manylinux2014_x86_64 -d .whl "$pkg"
    done
    [ -d .gpu/base ] || git worktree add -q --detach .gpu/base "$BASE"
    python3 tools/bench_device.py stats --save .gpu/cpu_stats.json
    du -sh .whl .gpu
    exit 0
fi

OUT=${OUT:-/tmp/gpu_check}
mkdir -p "$OUT"
exec > >(tee "$OUT/gpu_check.log") 2>&1
export PYTHONUNBUFFERED=1
unset PYTHONDONTWRITEBYTECODE                       # timed the way users meet it: pip install leaves bytecode
T0=$SECONDS
step() { echo; echo "=== $1 ($((SECONDS - T0)) s)"; }
BUDGET=${BUDGET:-380}                                # seconds for the whole run: the lease is 15 minutes, its start included
cap() { local left=$((BUDGET - (SECONDS - T0))); [ "$left" -lt "$1" ] && echo $((left > 10 ? left : 10)) || echo "$1"; }

step "the driver's OpenCL library"
nvidia-smi -L 2>&1 | head -3
ls -l /etc/OpenCL/vendors 2>&1; cat /etc/OpenCL/vendors/*.icd 2>/dev/null
ldconfig -p | grep -i -E 'libOpenCL|libnvidia-opencl' | head -5
if ! grep -qs nvidia /etc/OpenCL/vendors/*.icd; then   # the ICD loader finds NVIDIA's library by this file
    lib=$(ldconfig -p | grep -o '/[^ ]*libnvidia-opencl.so[.0-9]*' | head -1)
    [ -n "$lib" ] || lib=$(find / -name 'libnvidia-opencl.so*' 2>/dev/null | head -1)
    if [ -n "$lib" ]; then
        mkdir -p /tmp/icd && echo "$lib" > /tmp/icd/nvidia.icd && export OCL_ICD_VENDORS=/tmp/icd
        echo "no NVIDIA ICD file: using $lib through OCL_ICD_VENDORS=/tmp/icd"
    fi
fi

step "wheels"
if [ -z "${GPU_CHECK_NO_WHEELS:-}" ]; then          # (set it to rehearse the script where clisp's needs are installed)
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        || { echo "wheel install failed"; exit 1; }
fi
# bytecode for every tree timed here, as `pip install` leaves it for a user (without it each process
# compiles clisp's, pyopencl's and tifffile's sources again: 0.2 s of start-up on this project's VM)
python3 -m compileall -q -j 0 /tmp/site clisp tools .gpu/base/clisp > /dev/null 2>&1
export PYTHONPATH=/tmp/site
python3 - <<'EOF' || exit 1
import pyopencl as cl
for p in cl.get_platforms():
    for d in p.get_devices():
        print(f"{p.name} / {d.name}: {cl.device_type.to_string(d.type)}, {d.global_mem_size / 2**30:.0f} GiB, "
              f"host unified {bool(d.host_unified_memory)}")
EOF
export CLISP_DEVICE=${CLISP_DEVICE:-gpu} CLISP_CACHE_DIR=/tmp/clisp-cache
PY="python3"
CLISP="python3 -m clisp"

step "does a write into a buffer wait for the queue? (PoCL: yes, holding the GIL; engine README)"
timeout 60 $PY - <<'EOF' | tee "$OUT/write_wait.txt"
import time, numpy as np
from clisp.engine.runtime import get_runtime
rt = get_runtime(); cl = rt.cl
k = cl.Kernel(cl.Program(rt.context, "__kernel void slow(__global float *o, int n) { int i = get_global_id(0); "
              "float a = o[i]; for (int j = 0; j < n; j++) a = a * 0.999f + 1.0f; o[i] = a; }").build(), "slow")
big, small = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, 4 << 22), cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, 4096)
host, n = np.ones(1024, np.float32), 200
for _ in range(6):                                    # a kernel of 50-500 ms on this device
    rt.queue.finish(); t = time.perf_counter(); k(rt.queue, (1 << 22,), None, big, np.int32(n)); rt.queue.finish()
    if time.perf_counter() - t > 0.05:
        break
    n *= 10
for how, write in (("enqueue_copy, non-blocking", lambda: cl.enqueue_copy(rt.queue, small, host, is_blocking=False)),
                   ("a buffer made from the array", lambda: cl.Buffer(rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=host))):
    rt.queue.finish(); k(rt.queue, (1 << 22,), None, big, np.int32(n)); t0 = time.perf_counter()
    write(); t1 = time.perf_counter(); rt.queue.finish(); t2 = time.perf_counter()
    print(f"write wait: {how}: returned after {1e3 * (t1 - t0):.1f} ms of a kernel's {1e3 * (t2 - t0):.1f} ms")
EOF

step "in-process throughput, 24 MP, this tree and BASE ($BASE)"
SIZE=${SIZE:-6000x4000}
timeout $(cap 150) $PY tools/bench_device.py throughput --size $SIZE --repeat 5 --rounds 1 --baseline .gpu/base \
    | tee "$OUT/throughput.txt"

step "where a warm in-process call goes (bench_device.py profile)"
timeout $(cap 60) $PY tools/bench_device.py profile --size $SIZE

step "whole process: a 24 MP Bayer DNG simulated here, clisp quality against rawpy LINEAR"
W=/tmp/gpu_work; rm -rf $W; mkdir -p $W/many $W/out
$PY -c "from clisp.sim.charts import demo_chart; from clisp.io.imageio import write_image; write_image('$W/chart.png', demo_chart().image, encoded=False)"
timeout 120 $CLISP simulate $W/chart.png -o $W/bayer24.dng --cfa bayer --gain 4 --size $SIZE >/dev/null
cat > $W/rawpy_linear.py <<'EOF'
import sys, rawpy, tifffile
with rawpy.imread(sys.argv[1]) as raw:
    rgb = raw.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR, output_bps=16)
tifffile.imwrite(sys.argv[2], rgb)
EOF
$CLISP process $W/bayer24.dng -o $W/warm.tif >/dev/null                      # programs built and kept
(cd /tmp && PYTHONPATH=$ROOT/.gpu/base:/tmp/site python3 -m clisp process $W/bayer24.dng -o $W/warm_base.tif >/dev/null)
python3 - "$ROOT" "$W" <<'EOF' | tee "$OUT/whole.txt"
import os, subprocess, sys, time
root, w = sys.argv[1:3]
site = os.environ.get("PYTHONPATH", "")
runs = {"clisp": ([sys.executable, "-m", "clisp", "process", f"{w}/bayer24.dng", "-o", f"{w}/c.tif"], root),
        "base": ([sys.executable, "-m", "clisp", "process", f"{w}/bayer24.dng", "-o", f"{w}/b.tif"], f"{root}/.gpu/base"),
        "rawpy": ([sys.executable, f"{w}/rawpy_linear.py", f"{w}/bayer24.dng", f"{w}/r.tif"], "")}
for r in range(3):                                   # interleaved rounds
    for tool, (argv, tree) in runs.items():
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (tree, site) if p))
        start = time.perf_counter()
        subprocess.run(argv, env=env, cwd="/tmp", check=True, stdout=subprocess.DEVNULL)
        print(f"whole {tool} {r} {time.perf_counter() - start:.3f}", flush=True)
EOF
(cd /tmp && PYTHONPATH=$ROOT:/tmp/site python3 -m clisp process $W/bayer24.dng -o $W/c.tif --profile) | tee "$OUT/profile.txt"

step "${COUNT:-20} raws of $SIZE through one clisp process"
for i in $(seq -w 1 ${COUNT:-20}); do cp $W/bayer24.dng $W/many/r$i.dng; done
(cd /tmp && PYTHONPATH=$ROOT:/tmp/site timeout $(cap 120) python3 -m clisp process $W/many -o $W/out --format tif) \
    | tail -1 | tee "$OUT/many.txt"

if [ -n "${QUICK:-}" ]; then                          # a first look: where the whole process goes, no tests
    step "whole process under cProfile (QUICK)"
    (cd /tmp && PYTHONPATH=$ROOT:/tmp/site python3 - "$W" <<'EOF' | tee "$OUT/cprofile.txt"
import cProfile, io, pstats, sys, time
w = sys.argv[1]
start = time.perf_counter()
profiler = cProfile.Profile(); profiler.enable()
from clisp.engine import device_start
device_start.begin(None)
from clisp.app.cli import main
main(["process", f"{w}/bayer24.dng", "-o", f"{w}/cp.tif"])
profiler.disable()
print(f"in-process wall {time.perf_counter() - start:.3f} s")
for key, n in (("cumulative", 70), ("tottime", 30)):
    text = io.StringIO(); pstats.Stats(profiler, stream=text).sort_stats(key).print_stats(n)
    print("\n".join(l[:170] for l in text.getvalue().splitlines() if l.strip()))
EOF
    )
    step "table"
    cat "$OUT/whole.txt" "$OUT/many.txt" "$OUT/write_wait.txt"
    grep -E "wall|busy|per launch|start-up|load kept|write output|read tile|copy out|stage the" "$OUT/profile.txt"
    echo "done in $((SECONDS - T0)) s"
    exit 0
fi

step "every preset's 1 MP outputs against the CPU's (tests/tolerance.py's rule)"
$PY tools/bench_device.py stats --save "$W/gpu_stats.json"
$PY tools/bench_device.py stats --against "$W/gpu_stats.json" .gpu/cpu_stats.json | tee "$OUT/stats.txt"
# the Bayer raw with clipped lights through the best preset, whole, to compare pixel by pixel here
$PY - "$OUT" <<'EOF'
import sys
import numpy as np
sys.path.insert(0, "tools")
import bench_device, clisp
raw = bench_device.tiled_raw("bayer", (832, 1248), clip=True)
np.save(f"{sys.argv[1]}/clipped_best.npy", clisp.process(raw, preset="best").astype(np.float32))
EOF

step "kernel tests on the GPU (CLISP_DEVICE=$CLISP_DEVICE)"
# -o addopts="": one process (the GPU image's pytest may lack pytest-xdist, which addopts' -n needs)
timeout $(cap 240) $PY -m pytest -q -rfE -p no:cacheprovider -o addopts="" tests/modules tests/engine -m "not stress" \
    > "$OUT/tests.txt" 2>&1; tail -40 "$OUT/tests.txt"

step "the statistics pass on the GPU (issue 42, items 2 and 5): kernels against the reference, 24 MP"
timeout $(cap 120) $PY tools/bench_statistics.py $W/bayer24.dng --repeat 5 | tee "$W/statistics.txt"

step "table"
$PY - "$OUT" <<'EOF'
import re, statistics, sys
from pathlib import Path
out = Path(sys.argv[1])
def text(name):                                      # a step the budget cut short left no file
    f = out / name
    return f.read_text() if f.is_file() else ""
def last(name):
    lines = text(name).strip().splitlines()
    return lines[-1] if lines else "- (not run)"
whole = {}
for line in text("whole.txt").splitlines():
    _, tool, _, s = line.split()
    whole.setdefault(tool, []).append(float(s))
med = {k: statistics.median(v) for k, v in whole.items()}
prof = text("profile.txt")
startup = re.search(r"start-up \(interpreter, imports, OpenCL\)\s+([\d.]+)", prof)
loads = re.search(r"load kept programs \(start-up\)\s+([\d.]+)", prof)
busy = re.search(r"device busy (\d+) %", prof)
if {"clisp", "base", "rawpy"} <= med.keys():
    print(f"whole process, 24 MP Bayer DNG to TIFF, quality: clisp {med['clisp']:.2f} s, base {med['base']:.2f} s, "
          f"rawpy LINEAR {med['rawpy']:.2f} s: clisp / rawpy {med['clisp'] / med['rawpy']:.2f}")
    if startup:
        st = float(startup.group(1)) + (float(loads.group(1)) if loads else 0.0)
        print(f"  start-up {st:.2f} s (interpreter, imports, OpenCL {float(startup.group(1)):.2f}, program loads "
              f"{float(loads.group(1)) if loads else 0:.3f}); after start-up {med['clisp'] - st:.2f} s = "
              f"{(med['clisp'] - st) / med['rawpy']:.2f} x rawpy")
if busy:
    print(f"  --profile: device busy {busy.group(1)} % of the tile loop")
print("many files:", last("many.txt"))
print("\n".join(text("write_wait.txt").strip().splitlines()) or "write wait: - (not run)")
print("tests:", last("tests.txt"))
print("stats:", last("stats.txt"))
print(text("throughput.txt"))
EOF
echo "done in $((SECONDS - T0)) s"
