"""The CFA ablation (issue 32, item 2): RGB Bayer, LMS on the Bayer layout and the paper's LMS CFA,
Table 1 and Table 2 per channel, with and without the chroma denoiser.

    python tools/cfa_ablation.py [--data ../shared/data] [--step N] [--subset N] [--seeds S]
                                 [--levels none,4,8,16,32,64] [--results docs/RESULTS.md]

The paper (Section 3) argues in two steps: LMS filters on a Bayer sensor give lower quality red
than RGB Bayer, "but the difference is greatly reduced by the chrominance denoising step"; then
"doubling the density of L pixels brings red SNR and denoising artifacts roughly on par with RGB
Bayer cameras" (blue loses). This tool puts numbers on both, per output channel.

Sensors and demosaics (PIPELINES): ``bayer`` with ``ri`` (the quality preset's) and ``dlmmse`` (the
paper's Bayer baseline); ``lms-bayer`` (L, M, S where R, G, B are on RGGB) with the same two Bayer
demosaics, the better of which by mean Table 1 PSNR (denoiser on, every set and level) is reported
as its best; ``lms`` with ``guided`` (the quality preset's). One denoiser for all: the quality
preset's chroma denoise (ChromaDenoiseParams(), 3 levels), in each CFA's spectral space (BT.601 YUV
for RGB, the paper's Y = (L+M)/2 space for LMS), or none (the plain colour matrix). Pipelines and
simulation are tools/paper_tables.py's Runner and clisp.sim.simulate (docs/model.md sections 2, 3).

Table 1  PSNR (dB), tone-mapped (clip to [0, 1], sRGB-encode), 10 px border, seed 0, mean over the
         images of Kodak and McMaster (toolkit.load_scene: linear sRGB, cropped to multiples of 4)
         -- every ``--step``-th by file name -- at no noise and gains 4..64; over all channels (as
         clisp.metrics.psnr) and per channel R, G, B of the linear-sRGB output (each channel's own MSE).
Table 2  gray-panel SNR (dB) = 20 log10(mean / std) of the six neutral ColorChecker panels of the
         demo chart (central 32 x 32 px ROI), LINEAR output, per channel R, G, B
         (clisp.metrics.panel_snr), mean over ``--seeds`` noise seeds; the panels' mean and the
         darkest panel (P1).

With ``--results PATH`` the tables replace the section between the ``cfa-ablation`` markers of
PATH (toolkit.update_results); the prose around them is not touched.
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

import paper_tables as pt
from clisp.engine.runtime import get_runtime
from clisp.metrics import panel_snr, tone_map
from clisp.modules.chroma_denoise.stage import ChromaDenoiseParams
from clisp.sim.simulate import simulate

PIPELINES: tuple[tuple[str, str], ...] = (("bayer", "ri"), ("bayer", "dlmmse"), ("lms-bayer", "ri"),
                                          ("lms-bayer", "dlmmse"), ("lms", "guided"))
"""(CFA, demosaic) pairs run: RGB Bayer, LMS on the Bayer layout (both Bayer demosaics), the LMS CFA."""
LEVELS: list[int | None] = [None] + list(pt.GAINS)
CHANNELS = ("R", "G", "B")
SECTION = "cfa-ablation"
"""The marker name of the generated block in the results file."""

Key = tuple[str, str, bool]
"""(CFA, demosaic, denoise)."""


# ------------------------------------------------------------------------------------------
# metrics
# ------------------------------------------------------------------------------------------

def channel_psnr(output: np.ndarray, truth: np.ndarray, border: int = toolkit.BORDER) -> np.ndarray:
    """(4,) PSNR in dB: over all channels (= clisp.metrics.psnr, tone-mapped), then R, G, B, each
    from its own MSE. ``output``, ``truth``: H x W x 3 linear sRGB; ``border`` px cropped on every
    side; both clipped to [0, 1] and sRGB-encoded first (clisp.metrics.tone_map)."""
    a = tone_map(np.asarray(output, np.float64)[border:-border, border:-border])
    b = tone_map(np.asarray(truth, np.float64)[border:-border, border:-border])
    mse = ((a - b) ** 2).reshape(-1, 3).mean(axis=0)
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(1.0 / np.concatenate([[mse.mean()], mse]))


# ------------------------------------------------------------------------------------------
# Table 1
# ------------------------------------------------------------------------------------------

def scene_scores(scene: np.ndarray, gain: int | None, runner: pt.Runner,
                 pipelines: Sequence[tuple[str, str]] = PIPELINES) -> dict[Key, np.ndarray]:
    """One scene (H x W x 3 linear sRGB, sides multiples of 4) at one noise level (None = none):
    {(CFA, demosaic, denoise): (4,) PSNR all, R, G, B (channel_psnr)}. Seed 0; each CFA simulated
    once and processed with and without the denoiser (at no noise the denoiser does not run, so
    both keys hold the same figures)."""
    out: dict[Key, np.ndarray] = {}
    sims = {}
    for kind, name in pipelines:
        if kind not in sims:
            sims[kind] = simulate(scene, kind, gain=gain, seed=0)
        sim = sims[kind]
        without = channel_psnr(runner.run(sim.raw, name, False), sim.truth)
        out[(kind, name, False)] = without
        out[(kind, name, True)] = without if gain is None else channel_psnr(runner.run(sim.raw, name, True),
                                                                            sim.truth)
    return out


def table1_item(item: tuple, runner: pt.Runner, pipelines: Sequence[tuple[str, str]]) -> dict[Key, np.ndarray]:
    """One (image path, noise level) of Table 1 (scene_scores of toolkit.load_scene(path))."""
    path, gain = item
    return scene_scores(toolkit.load_scene(path), gain, runner, pipelines)


def mean_scores(per_item: list[dict[Key, np.ndarray]]) -> dict[Key, np.ndarray]:
    """The mean over items of each key's (4,) PSNR (the mean of the per-image dB, as Table 1)."""
    return {k: np.mean([s[k] for s in per_item], axis=0) for k in per_item[0]}


def table1(runner: pt.Runner, data: Path, step: int, subset: int | None, levels: list,
           pipelines: Sequence[tuple[str, str]] = PIPELINES,
           mapper: pt.Mapper = pt.serial) -> tuple[dict, dict[str, int]]:
    """({(set, gain): {(CFA, demosaic, denoise): mean (4,) PSNR}}, {set: images used}) for Kodak and
    McMaster: the first ``subset`` files by name (None = all), every ``step``-th of them."""
    out, used = {}, {}
    for set_name, image_set in pt.SETS.items():
        paths = toolkit.image_files(data, image_set, subset)[::step]
        used[set_name] = len(paths)
        items = [(path, gain) for path in paths for gain in levels]
        scores = mapper(table1_item, items, runner, pipelines, progress=f"ablation Table 1 {set_name}")
        for gain in levels:
            out[(set_name, gain)] = mean_scores([s for (_, g), s in zip(items, scores) if g == gain])
    return out, used


def best_demosaic(t1: dict, kind: str, pipelines: Sequence[tuple[str, str]] = PIPELINES) -> str:
    """The demosaic of ``kind`` with the highest mean all-channel PSNR, denoiser on, over every
    (set, level) of ``t1``."""
    names = [n for k, n in pipelines if k == kind]
    return max(names, key=lambda n: float(np.mean([v[(kind, n, True)][0] for v in t1.values()])))


# ------------------------------------------------------------------------------------------
# Table 2
# ------------------------------------------------------------------------------------------

def table2_item(item: tuple, runner: pt.Runner) -> dict[bool, np.ndarray]:
    """One (gain, CFA, demosaic, seed) on the demo chart: {denoise: (6, 3) gray-panel SNR (dB,
    linear output) per panel P1..P6 and channel R, G, B}."""
    gain, kind, name, seed = item
    demo = pt.chart()
    raw = simulate(demo.image, kind, gain=gain, seed=seed).raw
    return {d: panel_snr(runner.run(raw, name, d), demo.gray_rois) for d in (True, False)}


def table2(runner: pt.Runner, seeds: int, gains: Sequence[int] = pt.GAINS,
           pipelines: Sequence[tuple[str, str]] = PIPELINES, mapper: pt.Mapper = pt.serial) -> dict:
    """{(gain, CFA, demosaic, denoise): (6, 3) gray-panel SNR, mean over seeds 0..seeds-1}."""
    items = [(g, k, n, s) for g in gains for k, n in pipelines for s in range(seeds)]
    snrs = mapper(table2_item, items, runner, progress="ablation Table 2")
    out = {}
    for g in gains:
        for k, n in pipelines:
            for d in (True, False):
                out[(g, k, n, d)] = np.mean([r[d] for (gi, ki, ni, _), r in zip(items, snrs)
                                             if (gi, ki, ni) == (g, k, n)], axis=0)
    return out


# ------------------------------------------------------------------------------------------
# markdown
# ------------------------------------------------------------------------------------------

def level_name(gain: int | None) -> str:
    return "no noise" if gain is None else f"{gain}x"


def sensor_name(kind: str, name: str) -> str:
    return f"{kind} ({name.upper()})"


def md_table1(t1: dict, levels: list, pipelines: Sequence[tuple[str, str]]) -> list[str]:
    """Per set: a row per (sensor, denoiser on/off), a column per level; cells 'all (R/G/B)'."""
    lines = []
    for set_name in pt.SETS:
        lines += [f"**{set_name}** (PSNR dB, all channels, then R/G/B)", "",
                  "| sensor (demosaic) | denoise | " + " | ".join(level_name(g) for g in levels) + " |",
                  "|---|---|" + "---|" * len(levels)]
        for kind, name in pipelines:
            for d in (True, False):
                cells = []
                for g in levels:
                    v = t1[(set_name, g)][(kind, name, d)]
                    cells.append("=" if g is None and not d else f"{v[0]:.2f} ({v[1]:.2f}/{v[2]:.2f}/{v[3]:.2f})")
                lines.append(f"| {sensor_name(kind, name)} | {'on' if d else 'off'} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def md_steps(t1: dict, levels: list, lb: str) -> list[str]:
    """The two steps' differences (dB) per set and level: step 1, lms-bayer - bayer with the same
    demosaic ``lb``, red and blue, denoiser off and on; step 2, lms - bayer (RI and DLMMSE), red on
    and off, blue on; lms - lms-bayer, red and blue, off and on."""
    def d(s, g, a, b, den, c):
        return t1[(s, g)][a + (den,)][c] - t1[(s, g)][b + (den,)][c]
    L, B = "lms", "bayer"
    lines = [f"| set | noise | step 1: R, lms-bayer - bayer ({lb.upper()}), off / on | B, off / on "
             "| step 2: R, lms - bayer (RI) / (DLMMSE), on | R, same, off | B, lms - bayer (RI) / (DLMMSE), on "
             f"| R, lms - lms-bayer ({lb.upper()}), off / on | B, lms - lms-bayer, off / on |",
             "|---|---|---|---|---|---|---|---|---|"]
    lms, lmsb = (L, "guided"), ("lms-bayer", lb)
    for s in pt.SETS:
        for g in levels:
            r1 = [d(s, g, lmsb, (B, lb), den, 1) for den in (False, True)]
            b1 = [d(s, g, lmsb, (B, lb), den, 3) for den in (False, True)]
            r2 = [d(s, g, lms, (B, n), True, 1) for n in ("ri", "dlmmse")]
            r2o = [d(s, g, lms, (B, n), False, 1) for n in ("ri", "dlmmse")]
            b2 = [d(s, g, lms, (B, n), True, 3) for n in ("ri", "dlmmse")]
            r3 = [d(s, g, lms, lmsb, den, 1) for den in (False, True)]
            b3 = [d(s, g, lms, lmsb, den, 3) for den in (False, True)]
            lines.append(f"| {s} | {level_name(g)} | {r1[0]:+.2f} / {r1[1]:+.2f} | {b1[0]:+.2f} / {b1[1]:+.2f} "
                         f"| {r2[0]:+.2f} / {r2[1]:+.2f} | {r2o[0]:+.2f} / {r2o[1]:+.2f} | {b2[0]:+.2f} / {b2[1]:+.2f} "
                         f"| {r3[0]:+.2f} / {r3[1]:+.2f} | {b3[0]:+.2f} / {b3[1]:+.2f} |")
    return lines


def md_table2(t2: dict, gains: Sequence[int], pipelines: Sequence[tuple[str, str]]) -> list[str]:
    """A row per (gain, sensor): R/G/B SNR (mean of P1..P6) denoiser on and off, and P1 (darkest) on."""
    lines = ["| gain | sensor (demosaic) | on: R/G/B (mean of R, G, B) | off: R/G/B (mean) | P1 on: R/G/B |",
             "|---|---|---|---|---|"]
    for g in gains:
        for kind, name in pipelines:
            on, off = t2[(g, kind, name, True)], t2[(g, kind, name, False)]
            m_on, m_off = on.mean(axis=0), off.mean(axis=0)
            lines.append(f"| {g}x | {sensor_name(kind, name)} | {'/'.join(f'{x:.2f}' for x in m_on)} "
                         f"({m_on.mean():.2f}) | {'/'.join(f'{x:.2f}' for x in m_off)} ({m_off.mean():.2f}) "
                         f"| {'/'.join(f'{x:.2f}' for x in on[0])} |")
    return lines


def md_table2_steps(t2: dict, gains: Sequence[int], lb: str) -> list[str]:
    """Gray-panel SNR differences (dB, mean of P1..P6) for the two steps, red and blue, denoiser
    off and on (md_steps' columns)."""
    def d(g, a, b, den, c):
        return float(t2[(g,) + a + (den,)][:, c].mean() - t2[(g,) + b + (den,)][:, c].mean())
    lms, lmsb = ("lms", "guided"), ("lms-bayer", lb)
    lines = [f"| gain | step 1: R, lms-bayer - bayer ({lb.upper()}), off / on | B, off / on "
             "| step 2: R, lms - bayer (RI) / (DLMMSE), on | R, same, off | B, same, on | B, same, off "
             "| R, lms - lms-bayer, off / on | B, off / on |",
             "|---|---|---|---|---|---|---|---|---|"]
    for g in gains:
        r1 = [d(g, lmsb, ("bayer", lb), den, 0) for den in (False, True)]
        b1 = [d(g, lmsb, ("bayer", lb), den, 2) for den in (False, True)]
        r2 = [d(g, lms, ("bayer", n), True, 0) for n in ("ri", "dlmmse")]
        b2 = [d(g, lms, ("bayer", n), True, 2) for n in ("ri", "dlmmse")]
        r2o = [d(g, lms, ("bayer", n), False, 0) for n in ("ri", "dlmmse")]
        b2o = [d(g, lms, ("bayer", n), False, 2) for n in ("ri", "dlmmse")]
        r3 = [d(g, lms, lmsb, den, 0) for den in (False, True)]
        b3 = [d(g, lms, lmsb, den, 2) for den in (False, True)]
        lines.append(f"| {g}x | {r1[0]:+.2f} / {r1[1]:+.2f} | {b1[0]:+.2f} / {b1[1]:+.2f} | {r2[0]:+.2f} / {r2[1]:+.2f} "
                     f"| {r2o[0]:+.2f} / {r2o[1]:+.2f} | {b2[0]:+.2f} / {b2[1]:+.2f} | {b2o[0]:+.2f} / {b2o[1]:+.2f} "
                     f"| {r3[0]:+.2f} / {r3[1]:+.2f} | {b3[0]:+.2f} / {b3[1]:+.2f} |")
    return lines


def markdown(t1: dict, t2: dict, used: dict[str, int], totals: dict[str, int], step: int, seeds: int,
             levels: list, lb: str, minutes: float, command: str,
             pipelines: Sequence[tuple[str, str]] = PIPELINES) -> str:
    """The generated block (between the section markers): run facts, Table 1 per set, the step
    differences, Table 2 and its step differences."""
    lb_mean = {n: float(np.mean([v[("lms-bayer", n, True)][0] for v in t1.values()]))
               for k, n in pipelines if k == "lms-bayer"}
    start, end = toolkit.markers(SECTION)
    images = ", ".join(f"{used[s]} of {totals[s]} {s} images" for s in pt.SETS)
    lines = [
        start,
        "```sh",
        command,
        "```",
        "",
        f"Run: {minutes:.1f} min on {get_runtime().describe()} ({toolkit.cpu_model()}), revision "
        f"{toolkit.git_rev(toolkit.REPO, dirty=True)}. Table 1: {images}"
        f"{f' (every {step}-th by file name)' if step > 1 else ''}, seed 0; Table 2: demo chart, {seeds} seed(s). "
        f"Chroma denoise: {ChromaDenoiseParams()} (the quality preset's).",
        "",
        f"Best Bayer-layout demosaic for lms-bayer by this run (mean Table 1 PSNR, denoiser on, over both "
        f"sets and every level): **{lb.upper()}** ("
        + ", ".join(f"{n.upper()} {v:.2f} dB" for n, v in lb_mean.items()) + ").",
        "",
        "### Table 1 per channel",
        "",
        "Cells: PSNR over all channels (clisp.metrics.psnr), then R/G/B, each from its own MSE; "
        "tone-mapped (clip, sRGB-encode), 10 px border; '=' where the denoiser does not run (no noise).",
        "",
        *md_table1(t1, levels, pipelines),
        "### The two steps in Table 1 (dB; red R and blue B PSNR differences)",
        "",
        *md_steps(t1, levels, lb),
        "",
        "### Table 2 per channel: gray-panel SNR (dB), linear output",
        "",
        "Mean over the six neutral panels P1..P6 per channel R/G/B (in brackets the mean of the three: "
        "the paper's Table 2 figure, averaged over panels), denoiser on and off; P1 (darkest) with the denoiser on.",
        "",
        *md_table2(t2, sorted({k[0] for k in t2}), pipelines),
        "",
        "### The two steps in Table 2 (dB; red R and blue B SNR differences, mean of P1..P6)",
        "",
        *md_table2_steps(t2, sorted({k[0] for k in t2}), lb),
        end,
    ]
    return "\n".join(lines) + "\n"


def parse_levels(text: str) -> list:
    """'none,4,64' -> [None, 4, 64], each among LEVELS."""
    levels = [None if t.strip().lower() in ("none", "noiseless") else int(t) for t in text.split(",") if t.strip()]
    if not levels or any(g not in LEVELS for g in levels):
        raise argparse.ArgumentTypeError(f"levels must be among none,{','.join(map(str, pt.GAINS))}")
    return levels


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(ap)
    ap.add_argument("--step", type=int, default=1, help="every N-th image of each set (default 1: all)")
    ap.add_argument("--subset", type=int, default=None, help="the first N images of each set before --step")
    ap.add_argument("--seeds", type=int, default=2, help="noise seeds averaged in Table 2 (default 2)")
    ap.add_argument("--levels", type=parse_levels, default=LEVELS, metavar="none,4,...",
                    help="Table 1's noise levels (default none,4,8,16,32,64)")
    ap.add_argument("--results", type=Path, default=None,
                    help=f"write the tables into this markdown file between the {SECTION} markers")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    runner = pt.Runner(ChromaDenoiseParams(), None)
    t1, used = table1(runner, args.data, args.step, args.subset, args.levels)
    t_mid = time.perf_counter()
    gains = [g for g in args.levels if g is not None]
    t2 = table2(runner, args.seeds, gains)
    minutes = (time.perf_counter() - t0) / 60
    print(f"\nTable 1 {(t_mid - t0) / 60:.1f} min, Table 2 {(time.perf_counter() - t_mid) / 60:.1f} min")
    totals = {s: len(toolkit.image_files(args.data, i, args.subset)) for s, i in pt.SETS.items()}
    lb = best_demosaic(t1, "lms-bayer")
    argv_used = sys.argv[1:] if argv is None else argv
    command = "python tools/cfa_ablation.py " + " ".join(shlex.quote(a) for a in argv_used)
    text = markdown(t1, t2, used, totals, args.step, args.seeds, args.levels, lb, minutes, command.strip())
    print(text)
    if args.results is not None:
        toolkit.update_results(args.results, text, SECTION)
        print(f"wrote the {SECTION} section of {args.results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
