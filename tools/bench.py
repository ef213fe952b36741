"""Speed / quality benchmark of clisp's presets and demosaics beside peer demosaicers (issue 7).

Quality: for every scene (the demo chart plus the first --subset images of Kodak and McMaster)
and every gain of --gains (default 1, 8, 64), a Bayer and an LMS raw are simulated once
(clisp.sim.simulate, Airy optics, seed 0) and every method processes the SAME mosaic; PSNR (dB,
tone-mapped, 10 px border, clisp.metrics.psnr) against the simulation's ground truth, mean over
the scenes.

Methods
  clisp presets        fast / balanced / quality, for LMS and for Bayer (clisp.pipeline.PRESETS)
  clisp demosaic+dn    every demosaic of the CFA with the chroma denoiser off and on (denoise
                       depth of the 'quality' preset), where not already one of the presets
  cd bilinear / cd Malvar2004 / cd Menon2007
                       colour-demosaicing on the Bayer mosaic, black-subtracted, white-normalised
                       and multiplied by OUR pass-1 WB gains, then OUR colour matrix (NumPy)
  rawpy LINEAR / AHD / DCB / DHT / AAHD
                       LibRaw postprocess of the same Bayer raw written as a DNG by
                       clisp.io.rawfile.write_raw, with user_wb = our pass-1 gains (relative, as LibRaw
                       normalises them), output_color=raw, gamma (1, 1), no_auto_bright,
                       output_bps=16, user_flip=0; the 16-bit camera-RGB result is scaled to
                       our normalisation (per-channel level calibrated once per raw from channel
                       means, see rawpy_method) and OUR colour matrix applied. Bayer only.

Speed: megapixels per second of processing only (no simulation, no file writing except that
rawpy's DNG is written once before timing): a Kodak image (kodim23, or the demo chart without
--data) simulated at gain 8 and repeated (mirrored) to --speed-shape (default 3000x4000 = 12 MP);
best of --repeat after one warm-up. clisp: Pipeline.run (tiles from the planner, host padding,
upload, kernels, download) on PoCL/OpenCL; peers: their whole call plus our matrix.

Outputs: --csv (one row per method and gain: method, cfa, family, gain, psnr, mp_per_s,
pareto = on the front of all methods, pareto_same_cfa = on the front of the methods that
process the same CFA, i.e. Bayer clisp vs the Bayer peers) and --plot (MP/s on a log axis against PSNR, one panel per gain, Pareto front marked).

    python tools/bench.py [--data ../shared/data] [--subset 1] [--gains 1,8,64]
                          [--speed-shape 3000x4000] [--repeat 3] [--csv docs/bench.csv]
                          [--plot docs/bench.png]

Tools-only dependencies: matplotlib, rawpy, colour-demosaicing.
"""
from __future__ import annotations

import argparse
import itertools
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import BORDER, parse_shape, write_csv

from clisp.metrics import psnr
from clisp.pipeline import PRESETS, build_pipeline
from clisp.io.rawimage import RawImage
from clisp.engine.runtime import get_runtime
from clisp.sim.simulate import simulate

DEMOSAICS_BY_KIND = {"lms": ("bilinear", "hybrid", "guided"), "bayer": ("bilinear", "malvar", "dlmmse")}
RAWPY_ALGOS = ("LINEAR", "AHD", "DCB", "DHT", "AAHD")
CD_ALGOS = ("bilinear", "Malvar2004", "Menon2007")


@dataclass
class Method:
    name: str
    cfa: str                    # 'lms' or 'bayer'
    family: str                 # 'clisp preset', 'clisp', 'colour-demosaicing', 'rawpy'
    make: Callable[[RawImage], Callable[[], np.ndarray]]
    """make(raw) -> a callable doing the processing only (setup such as DNG writing excluded)."""


# ------------------------------------------------------------------------------ methods

def clisp_method(kind: str, name: str, family: str, **options) -> Method:
    def make(raw: RawImage) -> Callable[[], np.ndarray]:
        pipe = build_pipeline(raw, **options)
        return lambda: pipe.run(raw.data)
    return Method(name, kind, family, make)


def clisp_methods() -> list[Method]:
    methods = [clisp_method(kind, f"clisp {kind} {preset}", "clisp preset", preset=preset)
               for kind in ("lms", "bayer") for preset in PRESETS]
    for kind, names in DEMOSAICS_BY_KIND.items():
        for demosaic in names:
            for denoise in (False, True):
                covered = any(PRESETS[p]["demosaic"][kind] == demosaic
                              and (PRESETS[p]["denoise_levels"] > 0) == denoise for p in PRESETS)
                if not covered:
                    methods.append(clisp_method(kind, f"clisp {kind} {demosaic}{' +dn' if denoise else ''}",
                                                "clisp", preset="quality", demosaic=demosaic, denoise=denoise))
    return methods


def normalised_mosaic(raw: RawImage) -> np.ndarray:
    """Black-subtracted, white-normalised mosaic times our pass-1 gains (white-balanced camera)."""
    channel = raw.cfa.channel_map(*raw.shape)
    scale = raw.pass1_gains() / (raw.white_level - raw.black_level)
    return (raw.data - raw.black_level[channel]) * scale[channel]


def bayer_pattern(raw: RawImage) -> str:
    letters = "RGB"
    cmap = raw.cfa.channel_map(2, 2)
    return "".join(letters[int(c)] for c in cmap.ravel())


def apply_matrix(rgb_cam: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return np.einsum("ij,hwj->hwi", np.asarray(matrix, np.float32), rgb_cam.astype(np.float32))


def cd_method(algo: str) -> Method:
    def make(raw: RawImage) -> Callable[[], np.ndarray]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import colour_demosaicing as cd
        fn = {"bilinear": cd.demosaicing_CFA_Bayer_bilinear, "Malvar2004": cd.demosaicing_CFA_Bayer_Malvar2004,
              "Menon2007": cd.demosaicing_CFA_Bayer_Menon2007}[algo]
        pattern = bayer_pattern(raw)
        matrix = raw.colour_matrix

        def run() -> np.ndarray:
            return apply_matrix(fn(normalised_mosaic(raw), pattern), matrix)
        return run
    return Method(f"cd {algo}", "bayer", "colour-demosaicing", make)


_TMP = tempfile.TemporaryDirectory(prefix="clisp-bench-")
_COUNTER = itertools.count()


def libraw_options(raw: RawImage, algo: str) -> dict:
    """rawpy postprocess options for LibRaw's ``algo`` on ``raw``: camera RGB, linear, 16 bits,
    user_wb = our pass-1 gains (relative: LibRaw normalises them)."""
    import rawpy
    gains = raw.pass1_gains()
    wb = [float(gains[0]), float(gains[1]), float(gains[2]), float(gains[1])]   # R, G, B, G2
    return dict(demosaic_algorithm=getattr(rawpy.DemosaicAlgorithm, algo), user_wb=wb,
                output_color=rawpy.ColorSpace.raw, gamma=(1, 1), no_auto_bright=True,
                output_bps=16, user_flip=0, highlight_mode=rawpy.HighlightMode.Ignore,
                adjust_maximum_thr=0.0)   # else LibRaw rescales a raw whose maximum is below white


def libraw_level(raw: RawImage, rgb: np.ndarray) -> np.ndarray:
    """Per-channel factors taking LibRaw's output (H x W x 3) to our normalisation: LibRaw
    normalises the multipliers and scales to its own maximum, so the level is the ratio of the
    mean of our normalised mosaic to the mean of LibRaw's output at that channel's sites."""
    channel = raw.cfa.channel_map(*raw.shape)
    ours = normalised_mosaic(raw)
    return np.array([ours[channel == c].mean() / max(float(rgb[..., c][channel == c].mean()), 1e-12)
                     for c in range(3)], np.float32)


def rawpy_method(algo: str) -> Method:
    def make(raw: RawImage) -> Callable[[], np.ndarray]:
        import rawpy

        from clisp.io.rawfile import write_raw
        path = Path(_TMP.name) / f"bench_{next(_COUNTER)}.dng"     # a fresh file for every raw
        write_raw(path, raw)
        options = libraw_options(raw, algo)
        matrix = raw.colour_matrix
        with rawpy.imread(str(path)) as handle:                     # level calibrated outside the timing
            rescale = libraw_level(raw, handle.postprocess(**options).astype(np.float64))

        def run() -> np.ndarray:
            with rawpy.imread(str(path)) as handle:
                rgb = handle.postprocess(**options)
            return apply_matrix(rgb.astype(np.float32) * rescale, matrix)
        return run
    return Method(f"rawpy {algo}", "bayer", "rawpy", make)


def all_methods(peers: bool = True) -> list[Method]:
    methods = clisp_methods()
    if peers:
        methods += [cd_method(a) for a in CD_ALGOS] + [rawpy_method(a) for a in RAWPY_ALGOS]
    return methods


# ------------------------------------------------------------------------------ scenes

def load_scenes(data: Path | None, subset: int) -> list[toolkit.Scene]:
    """The demo chart, then the first ``subset`` Kodak and McMaster images (cropped to multiples of 4)."""
    scenes = toolkit.demo_charts()
    if data is None or subset <= 0:
        return scenes
    for image_set, load in ((toolkit.KODAK, toolkit.kodak), (toolkit.MCMASTER, toolkit.mcmaster)):
        found = load(data, subset, required=False)
        if not found:
            print(f"warning: no images in {data / image_set.folder}; {image_set.label} skipped", file=sys.stderr)
        scenes += [toolkit.Scene(f"{image_set.label}/{name}", image) for name, image in found]
    return scenes


def tile_to(scene: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The scene repeated, alternate copies mirrored, and cropped to ``shape`` (H, W)."""
    h, w = shape
    row = np.concatenate([scene, scene[:, ::-1]], axis=1)
    block = np.concatenate([row, row[::-1]], axis=0)
    reps = (-(-h // block.shape[0]), -(-w // block.shape[1]), 1)
    return np.tile(block, reps)[:h, :w]


# ------------------------------------------------------------------------------ measurement

def quality(methods: list[Method], scenes: list[tuple[str, np.ndarray]], gains: list[float],
            verbose: bool = True) -> dict[tuple[str, float], float]:
    """Mean PSNR over the scenes, per (method name, gain)."""
    scores: dict[tuple[str, float], list[float]] = {}
    for label, scene in scenes:
        for gain in gains:
            sims = {kind: simulate(scene, kind, gain=gain, seed=0) for kind in ("lms", "bayer")}
            for m in methods:
                sim = sims[m.cfa]
                out = m.make(sim.raw)()
                value = psnr(out, sim.truth, border=BORDER)
                scores.setdefault((m.name, gain), []).append(value)
            if verbose:
                print(f"  quality: {label} gain {gain:g} done", flush=True)
    return {k: float(np.mean(v)) for k, v in scores.items()}


def speed(methods: list[Method], scene: np.ndarray, shape: tuple[int, int], repeat: int,
          verbose: bool = True) -> dict[str, float]:
    """Best-of-``repeat`` MP/s of every method on ``scene`` tiled to ``shape``, gain 8."""
    big = tile_to(scene, shape)
    sims = {kind: simulate(big, kind, gain=8, optics="none", seed=0) for kind in ("lms", "bayer")}
    mp = shape[0] * shape[1] / 1e6
    result = {}
    for m in methods:
        _, best = toolkit.best_of(m.make(sims[m.cfa].raw), repeat, warmup=True)   # warm-up: kernel builds, pools
        result[m.name] = mp / best
        if verbose:
            print(f"  speed: {m.name:28s} {mp / best:8.2f} MP/s ({best:.2f} s)", flush=True)
    return result


def pareto(points: dict[str, tuple[float, float]]) -> set[str]:
    """Names not dominated in (speed, psnr): no other point at least as good in both, better in one."""
    front = set()
    for name, (s, q) in points.items():
        if not any((s2 >= s and q2 >= q) and (s2 > s or q2 > q) for n2, (s2, q2) in points.items() if n2 != name):
            front.add(name)
    return front


def rows_for(methods: list[Method], scores: dict, speeds: dict, gains: list[float]) -> list[dict]:
    rows = []
    for gain in gains:
        points = {m.name: (speeds[m.name], scores[(m.name, gain)]) for m in methods}
        front = pareto(points)
        front_cfa = set().union(*(pareto({m.name: points[m.name] for m in methods if m.cfa == kind})
                                  for kind in {m.cfa for m in methods}))
        for m in methods:
            rows.append(dict(method=m.name, cfa=m.cfa, family=m.family, gain=gain,
                             psnr=round(scores[(m.name, gain)], 3), mp_per_s=round(speeds[m.name], 3),
                             pareto=m.name in front, pareto_same_cfa=m.name in front_cfa))
    return rows


def plot(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    gains = sorted({r["gain"] for r in rows})
    fig, axes = plt.subplots(1, len(gains), figsize=(6 * len(gains), 5.5), squeeze=False)
    style = {"clisp preset": ("o", "C0"), "clisp": ("s", "C2"), "colour-demosaicing": ("^", "C1"),
             "rawpy": ("v", "C3")}
    for ax, gain in zip(axes[0], gains):
        sub = [r for r in rows if r["gain"] == gain]
        for r in sub:
            marker, colour = style[r["family"]]
            face = colour if r["cfa"] == "lms" or r["family"] != "clisp preset" and r["family"] != "clisp" else "white"
            ax.scatter(r["psnr"], r["mp_per_s"], marker=marker, edgecolors=colour, facecolors=face, s=50,
                       zorder=3)
            ax.annotate(r["method"].replace("clisp ", "") + (" +" if r["pareto_same_cfa"] else ""),
                        (r["psnr"], r["mp_per_s"]), fontsize=6,
                        xytext=(3, 2), textcoords="offset points")
        front = sorted((r for r in sub if r["pareto"]), key=lambda r: r["psnr"])
        ax.plot([r["psnr"] for r in front], [r["mp_per_s"] for r in front], "k--", lw=1, zorder=2,
                label="Pareto front")
        ax.scatter([r["psnr"] for r in front], [r["mp_per_s"] for r in front], s=160, facecolors="none",
                   edgecolors="k", zorder=4)
        ax.set_yscale("log")
        ax.set_xlabel("PSNR (dB, tone-mapped) - higher is better")
        ax.set_ylabel("speed (MP/s, log) - higher is better")
        ax.set_title(f"gain {gain:g}")
        ax.grid(True, which="both", alpha=0.3)
    handles = [plt.Line2D([], [], marker=m, color=c, ls="", label=f) for f, (m, c) in style.items()]
    handles.append(plt.Line2D([], [], color="k", ls="--", label="Pareto front, all (circled); '+' = same-CFA front"))
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8)
    fig.suptitle(title + "  (clisp: filled = LMS, hollow = Bayer)", fontsize=9)
    fig.tight_layout(rect=(0, 0.06, 1, 0.95))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def short_device() -> str:
    """'platform / device' without the platform's long version string."""
    text = get_runtime().describe()
    platform, _, device = text.partition(" / ")
    return f"{platform.split(' (')[0]} / {device}" if device else text


def run_bench(data: Path | None, subset: int, gains: list[float], speed_shape: tuple[int, int], repeat: int,
              csv_path: Path | None, plot_path: Path | None, peers: bool = True, verbose: bool = True) -> dict:
    """The whole benchmark; returns dict(rows, scenes, speed_scene, device, seconds)."""
    t0 = time.perf_counter()
    methods = all_methods(peers)
    scenes = load_scenes(data, subset)
    speed_name, speed_scene = "demo chart", scenes[0][1]
    if data is not None and toolkit.kodak_path(data, 23).exists():
        speed_name, speed_scene = "kodim23", toolkit.load_scene(toolkit.kodak_path(data, 23))
    if verbose:
        print(f"bench: {len(methods)} methods, {len(scenes)} scenes, gains {gains}, device {get_runtime().describe()}")
    scores = quality(methods, scenes, gains, verbose)
    speeds = speed(methods, speed_scene, speed_shape, repeat, verbose)
    rows = rows_for(methods, scores, speeds, gains)
    if csv_path is not None:
        write_csv(rows, csv_path)
    title = (f"{len(scenes)} scenes; speed on {speed_name} tiled to {speed_shape[1]}x{speed_shape[0]}, "
             f"best of {repeat}; {short_device()}")
    if plot_path is not None:
        plot(rows, plot_path, title)
    return dict(rows=rows, scenes=[s[0] for s in scenes], speed_scene=speed_name, speed_shape=speed_shape,
                repeat=repeat, device=get_runtime().describe(), seconds=time.perf_counter() - t0)


def summary(rows: list[dict]) -> list[str]:
    """Plain-text answers: presets on the front per gain; is 'fast' faster than every peer."""
    lines = []
    for gain in sorted({r["gain"] for r in rows}):
        sub = [r for r in rows if r["gain"] == gain]
        front = [r["method"] for r in sub if r["pareto"]]
        q = {r["method"]: r["pareto"] for r in sub if r["method"].endswith(" quality")}
        lines.append(f"gain {gain:g}: Pareto front (all methods) = {', '.join(front)}; 'quality' on it: "
                     + ", ".join(f"{k.split()[1]} {'yes' if v else 'no'}" for k, v in q.items()))
        for kind in ("lms", "bayer"):
            same = [r for r in sub if r["cfa"] == kind]
            q = [r for r in same if r["method"].endswith(" quality")]
            if same:
                lines.append(f"gain {gain:g}: {kind} front (methods on the same {kind} mosaic) = "
                             f"{', '.join(r['method'] for r in same if r['pareto_same_cfa'])}; 'quality' on it: "
                             + ("yes" if q and q[0]["pareto_same_cfa"] else "no"))
    sub = [r for r in rows if r["gain"] == rows[0]["gain"]]
    peers = [r for r in sub if r["family"] in ("rawpy", "colour-demosaicing")]
    if peers:
        fastest = max(peers, key=lambda r: r["mp_per_s"])
        for r in sub:
            if r["method"].endswith(" fast"):
                lines.append(f"{r['method']}: {r['mp_per_s']:.2f} MP/s vs fastest peer {fastest['method']} "
                             f"{fastest['mp_per_s']:.2f} MP/s -> {'faster than every peer' if r['mp_per_s'] > fastest['mp_per_s'] else 'NOT faster than every peer'}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(ap)
    ap.add_argument("--no-data", action="store_true", help="demo chart only (no Kodak/McMaster)")
    ap.add_argument("--subset", type=int, default=1, help="first N images of Kodak and of McMaster (default 1)")
    ap.add_argument("--gains", default="1,8,64")
    ap.add_argument("--speed-shape", default="3000x4000", help="HxW of the timing image (default 3000x4000, 12 MP)")
    toolkit.add_repeat_option(ap, 3, "timed runs per method after a warm-up, best kept")
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--csv", type=Path, default=toolkit.REPO / "docs" / "bench.csv")
    ap.add_argument("--plot", type=Path, default=toolkit.REPO / "docs" / "bench.png")
    args = ap.parse_args(argv)
    data = None if args.no_data else args.data
    result = run_bench(data, args.subset, [float(g) for g in args.gains.split(",")], parse_shape(args.speed_shape),
                       args.repeat, args.csv, args.plot, not args.no_peers)
    print(f"\n{'method':30s}" + "".join(f"{'PSNR g' + format(g, 'g'):>12s}" for g in sorted({r['gain'] for r in result['rows']}))
          + f"{'MP/s':>10s}")
    names = list(dict.fromkeys(r["method"] for r in result["rows"]))
    for name in names:
        rs = [r for r in result["rows"] if r["method"] == name]
        print(f"{name:30s}" + "".join(f"{r['psnr']:11.2f}{'*' if r['pareto'] else ' '}" for r in rs)
              + f"{rs[0]['mp_per_s']:10.2f}")
    print("(* = on the Pareto front at that gain)")
    for line in summary(result["rows"]):
        print(line)
    print(f"wrote {args.csv} and {args.plot} in {result['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
