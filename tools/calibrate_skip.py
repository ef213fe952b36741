"""Measure what the per-tile skips (clisp.pipeline.skip) save and cost: time and PSNR, default vs --no-skip.

    python tools/calibrate_skip.py [--gains 1,64] [--cfas lms,bayer] [--kodak 5,23] [--mcmaster 5,9]
                                   [--sky 2048x1536] [--tile N] [--repeat 2] [--data DIR]
    python tools/calibrate_skip.py --levels      # predicted visible chroma noise on grey fields
    python tools/calibrate_skip.py --cost        # analysis cost, ms per MP
    python tools/calibrate_skip.py --choice      # the noise-adaptive choice's calibration (clisp.pipeline.demosaic_choice)
    python tools/calibrate_skip.py --cli [--work DIR] [--scenes sky,kodak,mcm] [--repeat 3]
        # issue 13's acceptance: whole process (`clisp process X.dng -o Y.exr` against
        # `--no-skip`), 12 MP scenes: the sky, a 5 x 6 collage of Kodak and a 8 x 6 collage of
        # McMaster images; PSNR is the mean over the collage's images

Per scene, CFA and gain: the raw is simulated (clisp.sim.simulate, seed 1), the 'quality' preset
pipeline is built with skip=True (default) and skip=False (--no-skip: analysed, every tile full),
both run on OpenCL (best of --repeat, analysis time added to the default's), and PSNR
(tone-mapped, docs/model.md section 5) is taken against the simulation's truth. Data are read from
--data (never copied). Prints one row per case and the means.

First measurement (2 shared CPU cores, PoCL, OpenCL backend, automatic tiles, best of 2;
``--sky 2048x1536 --kodak 5,23 --mcmaster 5,9 --gains 1,64``). Thresholds: clisp.pipeline.skip's initial
ones (VISIBLE_LIGHT 8e-3). Time ratio = default (analysis included) / --no-skip:

    scene          cfa   gain  ratio  PSNR loss  paths
    sky 3.1 MP     lms   1     1.02   0.261 dB   light x 2 bands
    sky 3.1 MP     bayer 1     1.07   0.098 dB   light x 2
    kodim05        lms   1     1.30   0.040      light          kodim05 bayer 1: 1.27, 0.026
    kodim23 / mcm9 any   1     1.04-1.58  0     full (saturated colours)
    mcm5           lms   1     0.92   0.017      light
    all            any   64    1.00-1.50  0     full everywhere
    mean natural (4 images) gain 1: LMS 1.21 / 0.014 dB, Bayer 1.31 / 0.007 dB; gain 64: 1.24 / 0, 1.25 / 0

Findings: (1) no target is met: the light path (1 Haar level) saves only 5-30 % of the
denoiser, which is 30 % of the LMS pipeline (the guided demosaic is 70 %) and 75 % of Bayer's,
and the analysis (11-16 ms/MP at 12 MP, 23-32 ms/MP on 0.4 MP images) costs more than that on
small images, which are one tile, so the plan is all-or-nothing there. (2) Dropping the coarse
levels costs most on *flat* areas (sky: -0.26 dB LMS), where low-frequency chroma blotches are
what they remove: the rule must use flatness (allow ``light`` on textured tiles, keep ``full``
on flat ones), not noise visibility alone. (3) At gain 64 nothing is skipped (correct).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import kodak_path, mcmaster_path

from clisp.io.imageio import read_scene
from clisp.metrics import psnr
from clisp.pipeline import build_pipeline
from clisp.sim.simulate import simulate


def gradient(h: int, w: int) -> np.ndarray:
    """The skies' smooth gradient, linear sRGB (h x w x 3, float32): blue at the top, paler below."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    t = yy / h
    img = np.stack([0.25 + 0.35 * t, 0.40 + 0.30 * t, 0.80 - 0.10 * t], -1) * (0.9 + 0.1 * xx[..., None] / w)
    return img.astype(np.float32)


def sky(h: int, w: int, seed: int = 0) -> np.ndarray:
    """A mostly flat scene: a sky gradient with a textured strip at 80-90 % of the height."""
    from scipy.ndimage import gaussian_filter
    img = gradient(h, w)
    s0, s1 = int(0.8 * h), int(0.9 * h)
    tex = gaussian_filter(np.random.default_rng(seed).random((s1 - s0, w, 3)).astype(np.float32), (1.5, 1.5, 0))
    img[s0:s1] = 0.1 + 0.5 * (tex - tex.min()) / (tex.max() - tex.min())
    return img.astype(np.float32)


def striped_sky(h: int, w: int, period: int = 1000, seed: int = 0) -> np.ndarray:
    """Issue 30's sky: the gradient of :func:`sky` with a textured strip of period / 8 rows in the
    middle of every ``period`` rows (7/8 flat), so every full-width band of a plan holds some texture."""
    from scipy.ndimage import gaussian_filter
    img = gradient(h, w)
    rng = np.random.default_rng(seed)
    strip = period // 8
    for y0 in range((period - strip) // 2, h, period):
        y1 = min(y0 + strip, h)
        tex = gaussian_filter(rng.random((y1 - y0, w, 3)).astype(np.float32), (1.5, 1.5, 0))
        img[y0:y1] = 0.1 + 0.5 * (tex - tex.min()) / (tex.max() - tex.min())
    return img


def compare(name: str, scene: np.ndarray, cfa: str, gain: float, tile: int | None, repeat: int) -> dict:
    sim = simulate(scene, cfa=cfa, gain=gain, seed=1)
    row = {"scene": name, "cfa": cfa, "gain": gain, "mp": sim.raw.data.size / 1e6}
    for skip in (True, False):
        pipe, build = toolkit.best_of(lambda: build_pipeline(sim.raw, output="linear", skip=skip), 1)  # timed once
        out, seconds = toolkit.best_of(lambda: pipe.run(sim.raw.data, tile=tile), repeat)
        key = "skip" if skip else "full"
        row[f"t_{key}"] = seconds + (pipe.skipper.analysis.seconds if skip else 0.0)
        row[f"psnr_{key}"] = psnr(out, sim.truth)
        if skip:
            row["analysis"] = pipe.skipper.analysis.seconds
            row["paths"] = pipe.skip_plan.counts
            row["build"] = build
    return row


def collage(name: str, data: Path) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
    """A 12 MP natural scene and its images' regions (y0, y1, x0, x1): 'kodak' = 24 Kodak images
    (portrait ones turned) in 6 rows of 5 (3000 x 3840, the last row cut to 440 rows); 'mcm' = the
    18 McMaster images in 6 rows of 8 (3000 x 4000)."""
    if name == "kodak":
        ims = [read_scene(kodak_path(data, i)) for i in range(1, 25)]
        ims = [im if im.shape[0] == 512 else np.rot90(im) for im in ims]
        grid_, (ih, iw), h, w = (6, 5), (512, 768), 3000, 3840
    else:
        ims = [read_scene(mcmaster_path(data, i)) for i in range(1, 19)]
        grid_, (ih, iw), h, w = (6, 8), (500, 500), 3000, 4000
    rows = [np.concatenate([ims[(r * grid_[1] + c) % len(ims)] for c in range(grid_[1])], 1) for r in range(grid_[0])]
    scene = np.ascontiguousarray(np.concatenate(rows, 0)[:h, :w])
    regions = [(y, min(y + ih, h), x, x + iw) for y in range(0, h, ih) for x in range(0, w, iw) if min(y + ih, h) - y > 100]
    return scene, regions


def cli_acceptance(data: Path, work: Path, scenes: list[str], cfas: list[str], gains: list[str], repeat: int) -> int:
    """Simulate each scene (cached in ``work``), then time `clisp process` default against
    `--no-skip` (whole processes, interleaved, median of ``repeat``), score both and print the plan."""
    from clisp.io.imageio import read_image
    from clisp.io.rawfile import write_raw
    work.mkdir(parents=True, exist_ok=True)

    def timed(args: list[object]) -> tuple[float, str]:
        """Wall time (s) and stdout of this checkout's ``clisp ARGS`` as a process of its own."""
        r = toolkit.measure_process(toolkit.clisp_cmd(*(str(a) for a in args)), toolkit.repo_env(toolkit.REPO))
        if r.code:
            raise SystemExit(r.stderr)
        return r.wall_s, r.stdout

    print(f"{'scene':<7}{'cfa':<6}{'gain':>5}{'default s':>11}{'no-skip s':>11}{'ratio':>7}{'dB default':>12}"
          f"{'dB no-skip':>12}{'loss':>8}  plan")
    for name in scenes:
        if name in ("sky", "striped"):
            scene, regions = (sky if name == "sky" else striped_sky)(3000, 4000), [(10, 2990, 10, 3990)]
        else:
            scene, regions = collage(name, data)
        for cfa in cfas:
            for gain in gains:
                raw_path, truth_path = work / f"{name}_{cfa}_g{gain}.dng", work / f"{name}_{cfa}_truth_g{gain}.npy"
                if not raw_path.exists():
                    sim = simulate(scene, cfa=cfa, gain=float(gain), seed=1)
                    write_raw(raw_path, sim.raw)
                    np.save(truth_path, sim.truth.astype(np.float32))
                truth = np.load(truth_path)
                times: dict[str, list[float]] = {"skip": [], "noskip": []}
                scores = {}
                for k in range(repeat):
                    for mode, extra in (("skip", []), ("noskip", ["--no-skip"])):
                        out = work / f"out_{mode}.exr"
                        dt, _ = timed(["process", raw_path, "-o", out] + extra)
                        times[mode].append(dt)
                        if k == 0:
                            img = read_image(out)[0]
                            scores[mode] = float(np.mean([psnr(img, truth, region=r) for r in regions]))
                _, text = timed(["process", raw_path, "-o", work / "out_explain.exr", "--explain"])
                plan = "; ".join(" ".join(line.split()[:4]) for line in text.splitlines()
                                 if line.strip().split(" ")[0] in ("full", "light", "flat", "none", "mixed")
                                 and " tiles," in line)
                ts, tn = float(np.median(times["skip"])), float(np.median(times["noskip"]))
                print(f"{name:<7}{cfa:<6}{gain:>5}{ts:>11.2f}{tn:>11.2f}{ts / tn:>7.2f}{scores['skip']:>12.3f}"
                      f"{scores['noskip']:>12.3f}{scores['noskip'] - scores['skip']:>8.3f}  {plan}", flush=True)
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cli", action="store_true", help="issue 13's acceptance: whole process, 12 MP scenes")
    toolkit.add_work_option(ap, "--cli: raws and outputs", default=Path("/tmp/calibrate_skip"))
    toolkit.add_data_option(ap)
    ap.add_argument("--scenes", default="sky,kodak,mcm", help="--cli: sky, striped (issue 30's), kodak, mcm")
    ap.add_argument("--gains", default="1,64")
    ap.add_argument("--cfas", default="lms,bayer")
    ap.add_argument("--kodak", default="5,23")
    ap.add_argument("--mcmaster", default="5,9")
    ap.add_argument("--sky", default="2048x1536", help="WxH of the flat sky scene ('' to leave out)")
    ap.add_argument("--tile", type=int, default=None)
    toolkit.add_repeat_option(ap, 2, "timed runs, best kept (--cli: the median)")
    ap.add_argument("--choice", action="store_true",
                    help="the noise-adaptive choice's calibration (clisp.pipeline.demosaic_choice), on scenes made in code")
    ap.add_argument("--levels", action="store_true")
    ap.add_argument("--cost", action="store_true")
    args = ap.parse_args()
    if args.cli:
        return cli_acceptance(args.data, args.work.resolve(), args.scenes.split(","), args.cfas.split(","), args.gains.split(","),
                              args.repeat)
    if args.choice:
        return choice_calibration([float(g) for g in (args.gains if args.gains != "1,64" else CHOICE_GAINS).split(",")])
    if args.levels:
        return levels()
    if args.cost:
        return cost(args.data)
    scenes = []
    if args.sky:
        w, h = (int(v) for v in args.sky.lower().split("x"))
        scenes.append((f"sky {w}x{h}", sky(h, w)))
    for i in filter(None, args.kodak.split(",")):
        scenes.append((f"kodim{int(i):02d}", read_scene(kodak_path(args.data, int(i)))))
    for i in filter(None, args.mcmaster.split(",")):
        scenes.append((f"mcm{int(i)}", read_scene(mcmaster_path(args.data, int(i)))))
    rows = []
    print(f"{'scene':<16}{'cfa':<6}{'gain':>5}{'MP':>6}{'t skip':>9}{'t full':>9}{'ratio':>7}"
          f"{'dB skip':>9}{'dB full':>9}{'loss':>8}  paths")
    for cfa in args.cfas.split(","):
        for gain in (float(g) for g in args.gains.split(",")):
            for name, scene in scenes:
                r = compare(name, scene, cfa, gain, args.tile, args.repeat)
                rows.append(r)
                print(f"{r['scene']:<16}{cfa:<6}{gain:>5g}{r['mp']:>6.2f}{r['t_skip']:>9.3f}{r['t_full']:>9.3f}"
                      f"{r['t_skip'] / r['t_full']:>7.2f}{r['psnr_skip']:>9.3f}{r['psnr_full']:>9.3f}"
                      f"{r['psnr_full'] - r['psnr_skip']:>8.3f}  {r['paths']}", flush=True)
    for cfa in args.cfas.split(","):
        for gain in (float(g) for g in args.gains.split(",")):
            sel = [r for r in rows if r["cfa"] == cfa and r["gain"] == gain and not r["scene"].startswith("sky")]
            if sel:
                print(f"mean natural {cfa} gain {gain:g}: time ratio "
                      f"{np.mean([r['t_skip'] for r in sel]) / np.mean([r['t_full'] for r in sel]):.2f}, "
                      f"PSNR loss {np.mean([r['psnr_full'] - r['psnr_skip'] for r in sel]):.3f} dB")
    return 0


CHOICE_GAINS = "1,4,8,16,24,32,48,64"
"""Gains of ``--choice``'s rows."""


def choice_scenes() -> list[tuple[str, np.ndarray]]:
    """The calibration scenes of the noise-adaptive choice, made in code (Kodak and McMaster judge
    the choice, so they tune none of it): four dead-leaves charts, clisp's demo chart and a sky with
    its textured strip, 512 x 512."""
    from clisp.sim.charts import dead_leaves, demo_chart
    scenes = [(f"dead leaves {seed}", dead_leaves(512, seed=seed)) for seed in range(4)]
    scenes.append(("demo chart", demo_chart().image[:512, :512]))
    scenes.append(("sky", sky(640, 512)[128:640]))
    return scenes


def choice_candidates(raw: object) -> dict[str, object]:
    """The preset's demosaic and each alternative considered for ``raw`` (clisp.pipeline.demosaic_choice; the
    Bayer one, bilinear in place of RI, is measured but not in ALTERNATIVES)."""
    from clisp.pipeline import make_demosaic
    from clisp.pipeline.demosaic_choice import ALTERNATIVES
    if raw.cfa.kind == "lms":
        full = make_demosaic("guided", raw)
        return {"full": full, **{a.name: a.make(full) for a in ALTERNATIVES if a.stage == type(full).__name__}}
    return {"full": make_demosaic("ri", raw), "bilinear": make_demosaic("bilinear", raw)}


def choice_calibration(gains: list[float]) -> int:
    """Rows (kind, alternative, gain, sigma, mean dB, worst dB) of PSNR(alternative) - PSNR(full),
    the quality preset otherwise, on :func:`choice_scenes`; the sigma (clisp.pipeline.demosaic_choice.noise_sigma)
    is what clisp.pipeline.demosaic_choice.ALTERNATIVES' calibration rows hold."""
    from clisp.scene.noise import raw_noise
    from clisp.pipeline.demosaic_choice import noise_sigma
    from clisp.scene.white_balance import reference_channel
    scenes = choice_scenes()
    print("| CFA | alternative | gain | sigma at 18 % | mean dB | worst dB | worst scene |")
    print("|---|---|---:|---:|---:|---:|---|")
    for kind in ("lms", "bayer"):
        for gain in gains:
            deltas: dict[str, list[tuple[float, str]]] = {}
            sigma = 0.0
            for j, (name, scene) in enumerate(scenes):
                sim = simulate(scene, cfa=kind, gain=gain, seed=j)
                sigma = noise_sigma(raw_noise(sim.raw), reference_channel(sim.raw.cfa))
                scores = {k: psnr(build_pipeline(sim.raw, demosaic=stage, output="linear").run(sim.raw.data), sim.truth)
                          for k, stage in choice_candidates(sim.raw).items()}
                for k, v in scores.items():
                    if k != "full":
                        deltas.setdefault(k, []).append((v - scores["full"], name))
            for k, d in deltas.items():
                worst = min(d)
                print(f"| {kind} | {k} | {gain:g} | {sigma:.4f} | {np.mean([v for v, _ in d]):+.3f} | "
                      f"{worst[0]:+.3f} | {worst[1]} |", flush=True)
    return 0


def levels() -> int:
    from clisp.pipeline.skip import Skipper, visible_chroma_noise
    print("predicted visible chroma noise (median over blocks) on flat grey fields")
    for grey in (0.01, 0.05, 0.18, 0.5, 0.9):
        for cfa in ("lms", "bayer"):
            vals = []
            for gain in (1, 2, 4, 16, 64):
                raw = simulate(np.full((256, 256, 3), grey), cfa=cfa, gain=gain, seed=2).raw
                sk = Skipper.for_pipeline(raw, build_pipeline(raw).stages)
                vals.append(float(np.median(visible_chroma_noise(sk.denoiser, sk.analysis))))
            print(f"grey {grey:<5} {cfa:<6}" + " ".join(f"g{g}:{v:.2e}" for g, v in zip((1, 2, 4, 16, 64), vals)))
    return 0


def cost(data: Path) -> int:
    """The analysis's cost on a 12 MP raw (kodim05 simulated and repeated), ms per MP."""
    import dataclasses
    from clisp.scene.block_analysis import analyse
    scene = read_scene(kodak_path(data, 5))
    for cfa in ("lms", "bayer"):
        raw = simulate(scene, cfa=cfa, gain=1, seed=1).raw
        big = dataclasses.replace(raw, data=np.ascontiguousarray(np.tile(raw.data, (6, 6))[:3000, :4000]))
        best = min(analyse(big).seconds for _ in range(3))
        print(f"analysis {cfa}: 12 MP in {best * 1e3:.0f} ms = {best * 1e3 / 12:.1f} ms/MP")
    return 0


if __name__ == "__main__":
    sys.exit(main())
