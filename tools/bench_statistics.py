"""The statistics pass's cost (clisp.scene.statistics, issue 42 items 2 and 5), in process, warm:

    python tools/bench_statistics.py [RAW ...] [--repeat 7] [--size 6000x4000]

Per raw (camera raws through rawpy, our DNGs; with none given, a simulated Bayer and LMS raw of
``--size``), median of ``--repeat`` runs, each figure in ms:

* ``reference``  the NumPy reference's block table and noise strips (reference_statistics);
* ``+thumb``     its cell thumbnail (read on first need: white balance auto, pass 2, auto exposure);
* ``device``     the kernels of statistics.cl on the runtime's device (CLISP_DEVICE), tables read back;
* ``analysis``   the skip analysis from the tables (block_analysis.analyse: the noise strips' fit and
                 the per-block arithmetic; all of it host time), the figure that decides whether
                 skipping can pay on a GPU (clisp.pipeline.skip.why_not_skip);
* ``estimates``  white balance auto, pass 2 gray pixels, auto exposure and the noise estimate
                 from the tables (measure_scene's reading of them, host time).

It checks that the device's tables equal the reference's (integer raws: bit for bit) and prints
the device's name, so that a CPU run and a GPU run can be set side by side.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

import toolkit  # noqa: F401  (before clisp: puts this checkout on sys.path)

from clisp.engine.runtime import get_runtime
from clisp.io.rawfile import read_raw
from clisp.scene.block_analysis import analyse
from clisp.scene.exposure import auto_exposure_ev
from clisp.scene.noise import strip_noise
from clisp.scene.statistics import reference_statistics
from clisp.scene.statistics_device import device_statistics
from clisp.scene.white_balance import auto_gains
from clisp.scene.white_balance_pass2 import estimate_wb2
from clisp.sim.simulate import simulate


def timed(fn, repeat: int) -> tuple[float, object]:
    """Median wall time of ``fn()`` in ms over ``repeat`` runs (after one warm-up), and its last result."""
    result = fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times), result


def simulated(cfa: str, size: str) -> object:
    w, h = (int(v) for v in size.lower().split("x"))
    rng = np.random.default_rng(0)
    small = rng.random((h // 8, w // 8, 3)) ** 2
    img = np.kron(small, np.ones((8, 8, 1)))[:h, :w] * 0.8
    raw = simulate(img, cfa=cfa, gain=4, seed=1, optics="none").raw
    raw.metadata.pop("noise", None)          # treated as a camera raw: its noise is estimated
    return raw


def row(name: str, raw, rt, repeat: int) -> str:
    ref_ms, ref = timed(lambda: reference_statistics(raw), repeat)
    thumb_ms, _ = timed(lambda: reference_statistics(raw).thumbnail(), repeat)
    dev_ms, dev = timed(lambda: device_statistics(raw, rt), repeat)
    same = all(np.array_equal(getattr(ref.table, f), getattr(dev.table, f)) for f in ("sums", "clipped", "uniform"))
    close = np.allclose(ref.table.lap, dev.table.lap, rtol=1e-5, atol=1e-6 * max(1.0, np.abs(ref.table.lap).max()))
    an_ms, _ = timed(lambda: analyse(raw, statistics=dev), repeat)

    def estimates() -> None:
        auto_gains(raw, dev)
        gains2 = estimate_wb2(raw, "gray_pixels", dev)
        auto_exposure_ev(raw, gains2, 10.0, dev)
        strip_noise(raw, dev)

    est_ms, _ = timed(estimates, repeat)
    mp = raw.shape[0] * raw.shape[1] / 1e6
    return (f"| {name} | {mp:.1f} | {ref_ms:.0f} | {thumb_ms - ref_ms:+.0f} | {dev_ms:.0f} | "
            f"{an_ms:.0f} | {est_ms:.0f} | {'equal' if same and close else 'DIFFER'} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("raws", nargs="*")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--size", default="6000x4000")
    args = ap.parse_args()
    rt = get_runtime()
    print(f"device: {rt.device.name.strip()}; median of {args.repeat}, ms")
    print("| raw | MP | reference | +thumb | device | analysis (host) | estimates (host) | tables |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    cases = [(path.split("/")[-1], lambda p=path: read_raw(p)) for path in args.raws] or \
        [(f"simulated {cfa} {args.size}", lambda c=cfa: simulated(c, args.size)) for cfa in ("bayer", "lms")]
    for name, load in cases:
        print(row(name, load(), rt, args.repeat), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
