"""Regenerate docs/RESULTS.md: the paper's Table 1 and Table 2 beside ours, the spectral
ColorChecker colour error, and the speed/quality benchmark (tools/bench.py) with its plot and CSV.

Every number in the markdown except the paper's (its Tables 1 and 2 as published:
tools/paper_tables.PAPER_T1 and PAPER_T2, PAPER_T1_EXTRA here) comes from this run. Table 1 and
Table 2 use tools/paper_tables.py's machinery (Runner, table1, table2: same pipelines, PSNR and SNR
definitions, docs/model.md section 5); the "Charts" row (clisp.sim.charts.demo_chart) and
the spectral row (clisp.sim.spectral.simulate_spectral, compared with the paper's hyperspectral ISET
row) are scored here the same way (tone-mapped PSNR, 10 px border, chroma denoise on).

Two Bayer demosaics are run: ``dlmmse`` (the paper's Bayer baseline, DLMMSE; its figures and the
LMS leads over it stand beside the paper's) and, when clisp.pipeline.DEMOSAICS has it, ``ri``
(clisp's residual-interpolation Bayer demosaic, the ``quality`` preset's default: the strongest
fast Bayer), shown on a line of its own in each cell with the LMS lead over it.

    python tools/reproduce_paper.py [--data ../shared/data] [--subset N] [--seeds S]
        [--bench-subset N] [--speed-shape HxW] [--repeat R] [--out docs] [--scheduler ADDRESS]

``--scheduler ADDRESS`` runs the sweeps (Table 2 per gain, CFA and seed; Table 1 per image and
noise level; the chart and spectral rows per noise level) as a batch on that Dask cluster through
clisp.batch, with the same numbers as the default in-process run.
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from contextlib import contextmanager
from functools import partial
from typing import Iterator

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

import bench
import paper_tables as pt
from clisp.metrics import psnr
from clisp.engine.runtime import get_runtime
from clisp.sim.simulate import simulate
from clisp.sim.spectral import patch_delta_e, simulate_spectral, spectral_colorchecker
from clisp.modules.chroma_denoise.stage import ChromaDenoiseParams

PAPER_T1_EXTRA = {   # the paper's Table 1, verbatim (Kodak and IMAX/McMaster are in paper_tables.PAPER_T1)
    "ISET (hyperspectral)": {None: (47.10, 48.93), 4: (39.02, 41.23), 8: (37.48, 39.44), 16: (35.03, 37.28),
                             32: (32.86, 35.26), 64: (31.20, 33.55)},
    "Charts (RGB)": {None: (47.67, 47.50), 4: (36.94, 39.01), 8: (35.26, 37.16), 16: (33.03, 34.97),
                     32: (31.32, 33.13), 64: (30.14, 31.78)},
}
LEVELS = [None] + list(pt.GAINS)
EXTRA_BAYER = ("ri",)
"""Bayer demosaics run beside the paper's baseline (dlmmse) when registered in DEMOSAICS."""


def bayer_names(base: str) -> list[str]:
    """The Bayer demosaics of this run: ``base`` (the paper's baseline) first, then those of
    EXTRA_BAYER that clisp.pipeline.DEMOSAICS registers."""
    return [base] + [n for n in EXTRA_BAYER if n in pt.DEMOSAICS and n != base]


def label(name: str) -> str:
    """A demosaic's name as the tables print it (dlmmse -> DLMMSE, ri -> RI)."""
    return name.upper()


def pipelines(lms: str, bayer: str | list[str]) -> list[tuple[str, str]]:
    """(kind, demosaic) in the order of the chart and spectral rows' tuples: the first Bayer, the
    LMS, then the other Bayers (so that a single Bayer gives the (Bayer, LMS) pair)."""
    first, *others = pt.bayer_list(bayer)
    return [("bayer", first), ("lms", lms)] + [("bayer", n) for n in others]


def chart_item(gain, runner: pt.Runner, lms: str, bayer: str | list[str]) -> tuple[float, ...]:
    """(Bayer, LMS, *other Bayers) tone-mapped PSNR on the demo chart at one noise level;
    ``bayer``: one name or several (the first is the paper's baseline)."""
    scene = pt.chart().image
    scores = []
    for kind, name in pipelines(lms, bayer):
        sim = simulate(scene, kind, gain=gain, seed=0)
        scores.append(psnr(runner.run(sim.raw, name, True), sim.truth, border=toolkit.BORDER))
    return tuple(scores)


def chart_rows(runner: pt.Runner, lms: str, bayer: str | list[str], mapper: pt.Mapper = pt.serial) -> dict:
    """{gain: (Bayer, LMS, *other Bayers) tone-mapped PSNR} on the demo chart, chroma denoise on, seed 0."""
    return dict(zip(LEVELS, mapper(chart_item, LEVELS, runner, lms, bayer, progress="charts")))


def spectral_item(gain, runner: pt.Runner, lms: str, bayer: str | list[str]) -> tuple[tuple[float, ...], dict]:
    """Spectral ColorChecker at one noise level: (Bayer, LMS, *other Bayers) PSNR, and when
    noiseless the mean/max CIEDE2000 per (kind, demosaic)."""
    rois = spectral_colorchecker("lms").rois
    scores, de = [], {}
    for kind, name in pipelines(lms, bayer):
        sim = simulate_spectral(kind, gain=gain, seed=0)
        image = runner.run(sim.raw, name, True)
        scores.append(psnr(image, sim.truth, border=toolkit.BORDER))
        if gain is None:
            d = patch_delta_e(image, sim.truth, rois)
            de[(kind, name)] = (float(np.mean(d)), float(np.max(d)))
    return tuple(scores), de


def spectral_rows(runner: pt.Runner, lms: str, bayer: str | list[str],
                  mapper: pt.Mapper = pt.serial) -> tuple[dict, dict]:
    """Spectral ColorChecker: {gain: (Bayer, LMS, *other Bayers) PSNR} and the noiseless mean/max
    CIEDE2000 per (kind, demosaic)."""
    out, de = {}, {}
    for gain, (pair, d) in zip(LEVELS, mapper(spectral_item, LEVELS, runner, lms, bayer, progress="spectral")):
        out[gain] = pair
        de.update(d)
    return out, de


@contextmanager
def sweep_mapper(scheduler: str | None) -> Iterator[pt.Mapper]:
    """The Mapper of the per-image/per-gain sweeps: this process, or with ``scheduler`` the Dask
    cluster there through clisp.batch (each worker: one OpenCL context, one Runner). The tools'
    functions (toolkit's included) travel by value, so the workers need clisp, not this checkout's tools/."""
    if not scheduler:
        yield pt.serial
        return
    import cloudpickle
    from clisp.batch import dask_client, map_ordered
    for module in (toolkit, pt, sys.modules[__name__]):
        if module.__name__ != "__main__":              # __main__ travels by value anyway
            cloudpickle.register_pickle_by_value(module)
    with dask_client(scheduler=scheduler) as client:
        print(f"sweeps on the Dask cluster at {scheduler}: {len(client.scheduler_info()['workers'])} workers")
        yield partial(map_ordered, client)


def fmt_level(gain) -> str:
    return "no noise" if gain is None else f"{gain}x"


def md_table1(rows: dict[str, tuple[str, dict, dict]], others: list[str] = ()) -> list[str]:
    """Table 1's markdown: per cell ours (paper's Bayer)/LMS (lead), the paper's, then a line per
    other Bayer demosaic (``others``, in the order of the tuples' tail: chart_item) with the LMS lead
    over it."""
    lines = ["| set (ours: what was run) | " + " | ".join(fmt_level(g) for g in LEVELS) + " |",
             "|---|" + "---|" * len(LEVELS)]
    for set_label, (note, ours, paper) in rows.items():
        cells = []
        for g in LEVELS:
            b, lm, *extra = ours[g]
            pb, pl = paper[g]
            cells.append(f"{b:.2f}/{lm:.2f} ({lm - b:+.2f})<br>paper {pb:.2f}/{pl:.2f} ({pl - pb:+.2f})"
                         + "".join(f"<br>{label(n)} {x:.2f} (LMS - {label(n)} {lm - x:+.2f})"
                                   for n, x in zip(others, extra)))
        lines.append(f"| {set_label} ({note}) | " + " | ".join(cells) + " |")
    return lines


def md_table2(t2: dict, lms: str, bayer: str | list[str], seeds: int) -> list[str]:
    """Table 2's markdown: per gain and panel ours (paper's Bayer)/LMS, the paper's, then a line
    per other Bayer demosaic; the last column the mean LMS lead over each."""
    first, *others = pt.bayer_list(bayer)
    lead_head = f"mean lead of LMS over {label(first)} (paper)" + "".join(f"<br>over {label(n)}" for n in others)
    lines = ["| gain | " + " | ".join(f"P{k + 1}" for k in range(6)) + f" | {lead_head} |",
             "|---|" + "---|" * 7]
    for gain in pt.GAINS:
        b, lm = t2[(gain, "bayer", first)][True], t2[(gain, "lms", lms)][True]
        extra = [t2[(gain, "bayer", n)][True] for n in others]
        pb, pl = pt.PAPER_T2[gain]
        cells = [f"{b[k]:.2f}/{lm[k]:.2f}<br>paper {pb[k]:.2f}/{pl[k]:.2f}"
                 + "".join(f"<br>{label(n)} {x[k]:.2f}" for n, x in zip(others, extra)) for k in range(6)]
        lead, plead = float(np.mean(lm - b)), float(np.mean(np.subtract(pl, pb)))
        leads = "".join(f"<br>{float(np.mean(lm - x)):+.2f} over {label(n)}" for n, x in zip(others, extra))
        lines.append(f"| {gain}x | " + " | ".join(cells) + f" | {lead:+.2f} ({plead:+.2f}){leads} |")
    return lines


def md_bench(result: dict, csv_rel: str, png_rel: str) -> list[str]:
    rows = result["rows"]
    gains = sorted({r["gain"] for r in rows})
    lines = [f"![speed vs PSNR]({png_rel})", "",
             f"CSV: [{csv_rel}]({csv_rel}). Quality scenes: {', '.join(result['scenes'])}. Speed: "
             f"{result['speed_scene']} tiled (mirrored) to {result['speed_shape'][1]}x{result['speed_shape'][0]} "
             f"({result['speed_shape'][0] * result['speed_shape'][1] / 1e6:.1f} MP), simulated at gain 8, "
             f"processing only, best of {result['repeat']} after a warm-up, on {result['device']}. "
             "`*` = on the Pareto front (speed, PSNR) of all methods at that gain; `+` = on the front of "
             "the methods processing the same CFA (LMS: clisp only; Bayer: clisp and the peers). The "
             "all-methods front mixes LMS and Bayer outputs of the same scenes (different sensors).", "",
             "| method | CFA | " + " | ".join(f"PSNR gain {g:g}" for g in gains) + " | MP/s |",
             "|---|---|" + "---|" * (len(gains) + 1)]
    for name in dict.fromkeys(r["method"] for r in rows):
        rs = sorted((r for r in rows if r["method"] == name), key=lambda r: r["gain"])
        lines.append(f"| {name} | {rs[0]['cfa']} | " + " | ".join(f"{r['psnr']:.2f}{' *' if r['pareto'] else ''}{' +' if r['pareto_same_cfa'] else ''}"
                                                              for r in rs) + f" | {rs[0]['mp_per_s']:.2f} |")
    lines += ["", "Summary (computed from the rows above):", ""]
    lines += [f"- {line}" for line in bench.summary(rows)]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(ap)
    ap.add_argument("--subset", type=int, default=4,
                    help="first N images of Kodak and McMaster for Table 1 (0 = all; default 4)")
    ap.add_argument("--seeds", type=int, default=2, help="noise seeds for Table 2")
    ap.add_argument("--bench-subset", type=int, default=1)
    ap.add_argument("--speed-shape", default="3000x4000")
    toolkit.add_repeat_option(ap, 3, "the benchmark's timed runs per method, best kept")
    toolkit.add_out_option(ap, "docs", "RESULTS.md, bench.csv and bench.png")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run the Table 1/2, chart and spectral sweeps (per image and gain) on the Dask "
                         "cluster at ADDRESS (clisp.batch); the speed benchmark stays in this process")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    data = args.data
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    lms = next(n for n in pt.LMS_PREFERENCE if n in pt.DEMOSAICS)
    bayer = "dlmmse" if pt.demosaic_factory("dlmmse") is not None else "bilinear"
    bayers = bayer_names(bayer)                  # the paper's baseline first, then RI when registered
    others = bayers[1:]
    runner = pt.Runner(ChromaDenoiseParams(), None)
    times = {}

    subset = args.subset or None
    with sweep_mapper(args.scheduler) as mapper:
        t = time.perf_counter()
        t2 = pt.table2(runner, [lms], bayers, args.seeds, mapper)
        times["Table 2"] = time.perf_counter() - t
        t = time.perf_counter()
        t1 = pt.table1(runner, data, subset, [lms], bayers, mapper)
        times["Table 1 (Kodak, McMaster)"] = time.perf_counter() - t
        t = time.perf_counter()
        charts = chart_rows(runner, lms, bayers, mapper)
        spectral, delta_e = spectral_rows(runner, lms, bayers, mapper)
        times["Table 1 (charts, spectral)"] = time.perf_counter() - t
    t = time.perf_counter()
    csv_path, png_path = out / "bench.csv", out / "bench.png"
    result = bench.run_bench(data, args.bench_subset, [1.0, 8.0, 64.0], toolkit.parse_shape(args.speed_shape),
                             args.repeat, csv_path, png_path)
    times["bench"] = time.perf_counter() - t
    total = time.perf_counter() - t0

    def ours(set_name: str) -> dict:
        return {g: (t1[(set_name, g, "bayer", bayer, "with")][0], t1[(set_name, g, "lms", lms, "with")][0],
                    *(t1[(set_name, g, "bayer", n, "with")][0] for n in others))
                for g in LEVELS}
    n_all = {s: len(toolkit.image_files(data, image_set, required=False)) for s, image_set in pt.SETS.items()}
    n_set = {s: min(n_all[s], subset or n_all[s]) for s in pt.SETS}
    rows = {
        "ISET (hyperspectral)": ("spectral ColorChecker, clisp.sim.spectral", spectral, PAPER_T1_EXTRA["ISET (hyperspectral)"]),
        "Charts (RGB)": ("clisp demo chart", charts, PAPER_T1_EXTRA["Charts (RGB)"]),
        "Kodak (RGB)": (f"{n_set['Kodak']} of {n_all['Kodak']} Kodak images", ours("Kodak"), pt.PAPER_T1["Kodak"]),
        "IMAX (RGB)": (f"{n_set['McMaster']} of {n_all['McMaster']} McMaster images", ours("McMaster"), pt.PAPER_T1["McMaster"]),
    }
    argv_used = sys.argv[1:] if argv is None else argv
    command = "python tools/reproduce_paper.py " + " ".join(shlex.quote(a) for a in argv_used)
    md = [
        "# Results: the paper's tables beside clisp's",
        "",
        "Generated by `tools/reproduce_paper.py`; every number here except the paper's (its Tables 1 and 2 "
        "as published, in tools/paper_tables.py and tools/reproduce_paper.py) "
        "comes from that run. Regenerate with (from the repository root, venv active):",
        "",
        "```sh",
        command.strip(),
        "python tools/bench.py --subset {0} --speed-shape {1} --repeat {2} --csv docs/bench.csv --plot docs/bench.png"
        "   # the benchmark alone".format(args.bench_subset, args.speed_shape, args.repeat),
        "```",
        "",
        f"Run: {total / 60:.1f} min on {get_runtime().describe()} "
        f"({', '.join(f'{k} {v / 60:.1f} min' for k, v in times.items())}). "
        f"Pipelines: LMS demosaic `{lms}`; Bayer demosaic `{bayer}` ({label(bayer)}: the paper's Bayer "
        "baseline; every Bayer/LMS figure and LMS lead set beside the paper's is against it)"
        + "".join(f" and Bayer demosaic `{n}` ({label(n)}: clisp's residual-interpolation Bayer, the "
                  "`quality` preset's; the cells' lines headed " + label(n) + ")" for n in others)
        + f"; chroma denoise on ({ChromaDenoiseParams()}), as in tools/paper_tables.py.",
        "",
        f"**Size of this run:** Table 1 uses {n_set['Kodak']} of {n_all['Kodak']} Kodak and "
        f"{n_set['McMaster']} of {n_all['McMaster']} McMaster images (the first by file name; "
        "`--subset 0` = all); "
        f"Table 2 averages {args.seeds} noise seed(s); the benchmark uses {len(result['scenes'])} scenes. "
        "Charts and spectral rows use one seed (0).",
        "",
        f"## Table 1: PSNR (dB), tone-mapped, 10 px border, {label(bayer)}/LMS (LMS - {label(bayer)})"
        + "".join(f"; {label(n)} (LMS - {label(n)})" for n in others),
        "",
        f"Ours first ({label(bayer)} Bayer/LMS), the paper's below (its Bayer/LMS)"
        + "".join(f", then ours with the {label(n)} Bayer demosaic (`{n}`) and the LMS lead over it"
                  for n in others)
        + ". The paper's ISET row used hyperspectral scenes, which are not "
        "available; ours is the spectral ColorChecker of clisp.spectral (Stockman-Sharpe cones / "
        "Nikon D100 QE under D65). McMaster stands in for the paper's IMAX.",
        "",
        *md_table1(rows, others),
        "",
        "## Spectral ColorChecker colour error (noiseless, CIEDE2000 over the 24 patches)",
        "",
        "| CFA (demosaic) | mean | max |",
        "|---|---|---|",
        *[f"| {'LMS' if kind == 'lms' else 'Bayer'} (`{name}`) | {v[0]:.2f} | {v[1]:.2f} |"
          for (kind, name), v in sorted(delta_e.items(), key=lambda kv: kv[0][0] == "lms")],   # Bayers first
        "",
        "clisp.sim.spectral.patch_delta_e: mean colour of the central 32x32 px of each patch, output vs truth, "
        "after the full pipeline (Airy optics, demosaic, chroma denoise, fitted colour matrix).",
        "",
        f"## Table 2: gray-panel SNR (dB), linear output, mean of R, G, B; {label(bayer)}/LMS"
        + "".join(f"; {label(n)}" for n in others),
        "",
        f"Demo chart, {args.seeds} seed(s), chroma denoise on; panels P1 (darkest) .. P6. Per cell ours "
        f"({label(bayer)} Bayer/LMS), then the paper's (its Bayer/LMS)"
        + "".join(f", then ours with the {label(n)} Bayer demosaic (`{n}`)" for n in others)
        + f"; last column the mean LMS lead over {label(bayer)} (the paper's in brackets)"
        + "".join(f" and over {label(n)}" for n in others) + ".",
        "",
        *md_table2(t2, lms, bayers, args.seeds),
        "",
        "## Speed against quality (tools/bench.py)",
        "",
        *md_bench(result, csv_path.name, png_path.name),
        "",
    ]
    path = out / "RESULTS.md"
    path.write_text("\n".join(md))
    print(f"\nwrote {path} ({total / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
