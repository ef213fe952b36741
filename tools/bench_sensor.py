"""The sensor corrections against their oracles (issue 44).

    python tools/bench_sensor.py [--sets kodak,mcmaster,deadleaves] [--cfa lms,bayer] [--gains 1,16]
                                 [--cases pixels,warm,dark,shading,prnu,gainmap] [--subset N] [--frames 16]
                                 [--csv PATH] [--results docs/RESULTS.md]
    python tools/bench_sensor.py --tune --sets deadleaves [--cases pixels,warm] [--rho 0.25,0.5 ...]
                                 [--hot-slope 1,2 --hot-cap 0.1,0.13 ...]   a grid of the auto test's
                                 constants on the defective-pixel cases, on scenes made in code (sets
                                 deadleaves, deadleaves-full, textured, textured-coarse, textured-smooth)
    python tools/bench_sensor.py --false-positives --gains 64   defect-free raws: auto against off
    python tools/bench_sensor.py --gainmap-flatness [--seeds 8]   a grey field through a GainMap DNG, rawpy beside

A constant given once (``--hot-cap 0.1``) outside ``--tune`` replaces the stage's in the study and in
``--false-positives``: a candidate judged without editing the stage.

Every scene is simulated once without defects (``defect-free``, processed with the defaults) and
once per case with the sensor defects of that case (same scene, CFA, gain and noise seed; the
truth is the ideal sensor's). Each defective raw is processed three ways: ``corrected`` (what a
user does: the defaults, the dark or flat frames the simulator makes, the DNG's GainMap),
``oracle`` (the same correction given the true defect: the true bad-pixel map, the noiseless dark
frame, the true shading and PRNU) and ``off`` (the correction left out). Scores: PSNR against the
truth (tone-mapped, 10 px border, clisp.metrics.psnr) and, for the pixels case, the pixels whose
output lies more than 0.1 (sRGB-encoded, any channel) off the truth.

Cases (the defects; clisp.sim.defects):

* ``pixels``   hot pixels (0.05 %, level 0.5 of full scale) and dead pixels (0.05 %): 0.1 % of the sensor
* ``warm``     warm pixels (0.1 %, the simulator's level 0.05: an excess of 0.025-0.075 of full scale)
* ``dark``     dark current 5 e-/s over 2 s with its fixed pattern (DSNU 0.4), corrected by FRAMES dark frames
* ``shading``  lens shading to 0.5 at the corners with its colour shading, corrected by FRAMES flat frames
* ``prnu``     PRNU 2 %, corrected by FRAMES flat frames
* ``gainmap``  the shading of ``shading`` recorded in the raw as GainMap opcodes (OpcodeList2), applied
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import itertools
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import toolkit

CASES = ("pixels", "warm", "dark", "shading", "prnu", "gainmap")
PIXEL_CASES = ("pixels", "warm")
"""The cases of defective pixels: their oracle is the true map, and they count the far-off pixels."""
LUMA = np.array([0.2126, 0.7152, 0.0722])
"""Rec. 709 luminance of linear sRGB."""
SEED = 1
DEFECT_SEED = 7


def defects_for(case: str):
    from clisp.sim.defects import SensorDefects
    return {"pixels": SensorDefects(hot=0.0005, dead=0.0005, seed=DEFECT_SEED),
            "warm": SensorDefects(warm=0.001, seed=DEFECT_SEED),
            "dark": SensorDefects(dark_current=5.0, exposure_time=2.0, seed=DEFECT_SEED),
            "shading": SensorDefects(shading=0.5, seed=DEFECT_SEED),
            "prnu": SensorDefects(prnu=0.02, seed=DEFECT_SEED),
            "gainmap": SensorDefects(shading=0.5, seed=DEFECT_SEED)}[case]


def far_off(output: np.ndarray, truth: np.ndarray, border: int = 10) -> int:
    """Pixels whose sRGB-encoded output lies more than 0.1 off the truth in any channel."""
    from clisp.metrics import tone_map
    a = tone_map(np.clip(output, 0, 1))[border:-border, border:-border]
    b = tone_map(np.clip(truth, 0, 1))[border:-border, border:-border]
    return int(np.count_nonzero(np.abs(a - b).max(axis=-1) > 0.1))


def variants(case: str, sim, gain, frames: int) -> dict[str, dict]:
    """The process options of corrected / oracle / off for one defective raw."""
    from clisp.sim import defects as sd
    d = defects_for(case)
    raw = sim.raw
    if case in PIXEL_CASES:
        return {"corrected": {}, "oracle": {"bad_pixels": sd.bad_sites(d, raw.shape)}, "off": {"bad_pixels": "off"}}
    if case == "dark":
        return {"corrected": {"dark": sd.frames(raw, d, "dark", frames, gain, 1000)},
                "oracle": {"dark": [sd.oracle_frame(raw, d, "dark", gain)]}, "off": {}}
    if case in ("shading", "prnu"):
        return {"corrected": {"flat": sd.frames(raw, d, "flat", frames, gain, 2000)},
                "oracle": {"flat": [sd.oracle_frame(raw, d, "flat", gain)]}, "off": {}}
    return {"corrected": {}, "oracle": {"flat": [sd.oracle_frame(raw, d, "flat", gain)]}, "off": {"opcodes": False}}


def simulate_case(scene: np.ndarray, cfa: str, gain: float, case: str):
    from clisp.sim import defects as sd
    from clisp.sim.simulate import simulate
    d = defects_for(case)
    sim = simulate(scene, cfa=cfa, gain=gain, seed=SEED, defects=d)
    if case == "gainmap":
        sim.raw.metadata["opcodes"] = sd.gain_map_opcodes(d, sim.raw.cfa, sim.raw.shape)
    return sim


def study(args: argparse.Namespace) -> list[dict]:
    import clisp
    from clisp.metrics import psnr
    from clisp.sim.simulate import simulate
    with_constants(given_constants(args))
    rows = []
    scenes = scene_list(args)
    start = time.perf_counter()
    for set_name, scene in scenes:
        for cfa in args.cfa:
            for gain in args.gains:
                clean = simulate(scene.image, cfa=cfa, gain=gain, seed=SEED)
                out = clisp.process(clean.raw)
                base = dict(set=set_name, image=scene.name, cfa=cfa, gain=gain)
                rows.append(dict(base, case="-", variant="defect-free", psnr=psnr(out, clean.truth),
                                 far_off=far_off(out, clean.truth)))
                for case in args.cases:
                    sim = simulate_case(scene.image, cfa, gain, case)
                    for name, options in variants(case, sim, gain, args.frames).items():
                        out = clisp.process(sim.raw, **options)
                        rows.append(dict(base, case=case, variant=name, psnr=psnr(out, clean.truth),
                                         far_off=far_off(out, clean.truth) if case in PIXEL_CASES else ""))
                print(f"{time.perf_counter() - start:7.0f} s  {set_name} {scene.name} {cfa} gain {gain:g}: "
                      + "  ".join(f"{r['case']}/{r['variant']} {r['psnr']:.2f}" for r in rows[-(1 + 3 * len(args.cases)):]),
                      flush=True)
    return rows


TEXTURED_SETS = {"textured": {}, "textured-coarse": {"rmin": 3.0},
                 "textured-smooth": {"rmin": 8.0, "rmax": 128.0, "contrast": 0.1}}
"""Tuning sets of clisp.sim.charts.textured_leaves (its arguments): ``textured-smooth`` matches the
photos' local statistics (sensor README)."""


def scene_list(args: argparse.Namespace) -> list[tuple[str, object]]:
    out = []
    for set_name in args.sets:
        if set_name == "deadleaves":
            scenes = fine_dead_leaves(4)
        elif set_name == "deadleaves-full":
            scenes = fine_dead_leaves(4, levels=(0.05, 1.0))
        elif set_name in TEXTURED_SETS:
            from clisp.sim.charts import textured_leaves
            scenes = [toolkit.Scene(f"{set_name}_{seed}", textured_leaves(384, seed=seed, **TEXTURED_SETS[set_name]))
                      for seed in range(4)]
        else:
            loader = toolkit.kodak if set_name == "kodak" else toolkit.mcmaster
            scenes = loader(args.data)
        out += [(set_name, s) for s in scenes[::args.subset]]
    return out


def fine_dead_leaves(count: int, size: int = 384, levels: tuple[float, float] = (0.05, 0.95)) -> list[toolkit.Scene]:
    """The tuning set, made in code: dead leaves down to discs of 0.4 px radius (clisp.sim.charts),
    whose points through the lens are the one-pixel details (bright and dark, in one channel or all)
    that a defect search must leave alone; seeds 0..count - 1. ``levels``: the discs' sRGB-encoded
    range; ``deadleaves-full`` takes it to 1.0, so that some of the ground a defect lies on clips (a
    saturated colour, as photos of flowers and fabrics have: samples above 0.9 linear are none of the
    default set's, 4 % of McMaster's)."""
    from clisp.sim.charts import dead_leaves
    tag = "" if levels == (0.05, 0.95) else f"_{levels[0]:g}_{levels[1]:g}"
    return [toolkit.Scene(f"dead_leaves_fine{tag}_{seed}", dead_leaves(size, seed=seed, rmin=0.4, rmax=32.0, levels=levels))
            for seed in range(count)]


def summary(rows: list[dict]) -> list[str]:
    """Per set, CFA, gain and case: mean PSNR of each variant, corrected - oracle, corrected -
    defect-free, off - corrected (the loss the correction prevents), and the far-off counts."""
    lines = ["| set | CFA | gain | case | defect-free | corrected | oracle | off | corrected - oracle | "
             "corrected - defect-free | loss prevented | pixels > 0.1 off: corrected / defect-free |",
             "|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    keys = sorted({(r["set"], r["cfa"], r["gain"]) for r in rows}, key=lambda k: (k[0], k[1], k[2]))
    for s, cfa, gain in keys:
        sub = [r for r in rows if (r["set"], r["cfa"], r["gain"]) == (s, cfa, gain)]
        free = [r for r in sub if r["variant"] == "defect-free"]
        free_psnr = statistics.mean(r["psnr"] for r in free)
        for case in CASES:
            got = {v: [r for r in sub if r["case"] == case and r["variant"] == v] for v in ("corrected", "oracle", "off")}
            if not got["corrected"]:
                continue
            m = {v: statistics.mean(r["psnr"] for r in rs) for v, rs in got.items()}
            far = ""
            if case in PIXEL_CASES:
                far = f"{sum(r['far_off'] for r in got['corrected'])} / {sum(r['far_off'] for r in free)}"
            lines.append(f"| {s} | {cfa} | {gain:g} | {case} | {free_psnr:.2f} | {m['corrected']:.2f} | "
                         f"{m['oracle']:.2f} | {m['off']:.2f} | {m['corrected'] - m['oracle']:+.3f} | "
                         f"{m['corrected'] - free_psnr:+.3f} | {m['corrected'] - m['off']:+.2f} | {far} |")
    return lines


TUNED = ("k", "alpha", "gamma", "z", "rho", "kr", "k_cold", "hot_slope", "hot_cap")
"""The auto test's constants --tune takes a grid of (DefectTest's fields; the stage's values by default)."""
CONSTANT_HELP = {"k": "noise sigmas of a hot pixel's test", "alpha": "share of the neighbours' range a bad pixel must also exceed",
                 "gamma": "most a hot pixel's 4 nearest pixels may carry of its excess",
                 "z": "the support test's noise margin", "rho": "the dead pixels' ratio to their lowest neighbour",
                 "kr": "noise sigmas of the ratio test", "k_cold": "noise sigmas of a dead pixel's test",
                 "hot_slope": "share of its highest neighbour's level a hot pixel must exceed it by",
                 "hot_cap": "most that share asks, normalised units"}
"""--<constant>'s help: what each of TUNED is."""


def given_constants(args: argparse.Namespace) -> dict[str, float]:
    """The auto test's constants given on the command line (the first value of each), for a study or
    --false-positives run with other constants than the stage's."""
    return {name: getattr(args, name)[0] for name in TUNED if getattr(args, name)}


def with_constants(constants: dict[str, float]) -> None:
    """Have every later process run the auto test with ``constants`` in place of the stage's."""
    import clisp.pipeline.corrections as corr
    if constants:
        original = corr.defect_test
        corr.defect_test = lambda raw, noise=None: (dataclasses.replace(original(raw, noise)[0], **constants), "given")


def tune(args: argparse.Namespace) -> None:
    """PSNR of the defective-pixel cases (``--cases``, of PIXEL_CASES: corrected, and the defect-free
    raw with the search on and off) for a grid of the auto test's constants."""
    import clisp
    import clisp.pipeline.corrections as corr
    from clisp.metrics import psnr
    from clisp.modules.sensor import stage
    from clisp.sim.defects import bad_sites
    from clisp.sim.simulate import simulate
    original = corr.defect_test
    values = [getattr(args, name) or [getattr(stage, name.upper())] for name in TUNED]
    grid = [dict(zip(TUNED, p)) for p in itertools.product(*values)]
    cases = [c for c in args.cases if c in PIXEL_CASES] or ["pixels"]
    results: dict = {i: [] for i in range(len(grid))}
    for set_name, scene in scene_list(args):
        for cfa in args.cfa:
            for gain in args.gains:
                clean = simulate(scene.image, cfa=cfa, gain=gain, seed=SEED)
                sims = {case: simulate_case(scene.image, cfa, gain, case) for case in cases}
                free_off = clisp.process(clean.raw, bad_pixels="off")
                offs = {case: psnr(clisp.process(sim.raw, bad_pixels="off"), clean.truth) for case, sim in sims.items()}
                oracles = {case: psnr(clisp.process(sim.raw, bad_pixels=bad_sites(defects_for(case), sim.raw.shape)), clean.truth)
                           for case, sim in sims.items()}           # a map alone: no search, the same for every setting
                for i, p in enumerate(grid):
                    corr.defect_test = lambda raw, noise=None, p=p: (dataclasses.replace(original(raw, noise)[0], **p), "tuned")
                    free = clisp.process(clean.raw)
                    changed = output_change(free, free_off) > TOLERANCE
                    for case, sim in sims.items():
                        out = clisp.process(sim.raw)
                        results[i].append({"cfa": cfa, "gain": gain, "case": case, "corrected": psnr(out, clean.truth),
                                           "free": psnr(free, clean.truth), "free_off": psnr(free_off, clean.truth),
                                           "oracle": oracles[case], "off": offs[case], "changed": changed,
                                           "far": far_off(out, clean.truth), "far_free": far_off(free_off, clean.truth)})
                corr.defect_test = original
        print(f"{scene.name} done", flush=True)
    for i, res in results.items():
        label = " ".join(f"{k} {v:g}" for k, v in grid[i].items())
        for case in cases:
            for cfa in args.cfa:
                for gain in args.gains:
                    r = [x for x in res if (x["cfa"], x["gain"], x["case"]) == (cfa, gain, case)]
                    if not r:
                        continue
                    m = {key: statistics.mean(x[key] for x in r) for key in ("corrected", "free", "free_off", "oracle", "off")}
                    print(f"{label} {case} {cfa} gain {gain:g}: corrected - defect-free (search off) "
                          f"{m['corrected'] - m['free_off']:+.3f} dB, - oracle {m['corrected'] - m['oracle']:+.3f}, "
                          f"- search off {m['corrected'] - m['off']:+.3f}, search on the defect-free raw "
                          f"{m['free'] - m['free_off']:+.3f} dB, far off {sum(x['far'] for x in r)} / "
                          f"{sum(x['far_free'] for x in r)}, defect-free raws changed {sum(x['changed'] for x in r)} of {len(r)}")


TOLERANCE = 1e-5
"""The tolerance rule: the largest output difference (relative where the output exceeds 1) by which a
defect-free raw counts as unchanged by the search (the acceptance's "no false corrections")."""


def output_change(on: np.ndarray, off: np.ndarray) -> float:
    """The largest difference of two outputs, relative where they exceed 1 (the tolerance rule's measure)."""
    return float(np.max(np.abs(on - off) / np.maximum(1.0, np.abs(off))))


def false_positives(args: argparse.Namespace) -> None:
    """Defect-free raws: the search on against off, per image (pixels the test replaced, the largest
    output difference; the tolerance rule is 1e-5)."""
    import clisp
    from clisp.pipeline import build_pipeline
    from clisp.modules.sensor.stage import FOUND
    from clisp.sim.simulate import simulate
    with_constants(given_constants(args))
    total = changed = 0
    for set_name, scene in scene_list(args):
        for cfa in args.cfa:
            for gain in args.gains:
                clean = simulate(scene.image, cfa=cfa, gain=gain, seed=SEED)
                pipe = build_pipeline(clean.raw)
                on = pipe.run(clean.raw.data)
                found = pipe.stats.counts.get(FOUND)
                off = clisp.process(clean.raw, bad_pixels="off")
                err = output_change(on, off)
                total += 1
                changed += err > TOLERANCE
                print(f"{set_name} {scene.name} {cfa} gain {gain:g}: {found} pixels replaced, largest difference "
                      f"{err:.2e}{' CHANGED' if err > TOLERANCE else ''}", flush=True)
    print(f"{changed} of {total} defect-free raws changed beyond the tolerance rule (1e-5)")


def gainmap_flatness(args: argparse.Namespace) -> None:
    """A grey field (0.18) through a lens with shading 0.5 and its colour shading, recorded as GainMap
    opcodes in our DNG (written and read back): the mean corner-to-centre luminance ratio, its
    difference to the defect-free raw's (%), and the largest CIEDE2000 between an output's corner
    colour and the defect-free output's (each corner scaled to the defect-free corner's luminance,
    so this is the colour alone), for clisp with the opcodes, clisp --no-opcodes and rawpy's output of
    the same DNG (LibRaw applies no opcode; Bayer only).

    Each figure is of the corner and centre colours averaged over ``--seeds`` noise seeds (the same
    seeds for the GainMap and the defect-free raws): one patch's mean colour varies by 0.5-0.75 % from
    seed to seed at gain 16 on the LMS camera (its sparse S channel's noise through the colour
    matrix), which alone puts two defect-free raws 0.5-1 CIEDE2000 apart. The line "defect-free,
    other seeds" measures that floor: the defect-free raw with as many further seeds against it."""
    import tempfile
    import clisp
    from clisp.io.rawfile import read_raw, write_raw
    from clisp.metrics import ciede2000
    from clisp.sim import defects as sd
    from clisp.sim.simulate import simulate
    grey = np.full((args.size[1], args.size[0], 3), 0.18)
    for cfa in args.cfa:
        for gain in args.gains:
            d = defects_for("gainmap")
            sums: dict[str, np.ndarray] = {}
            add = functools.partial(add_colours, sums, weight=1.0 / args.seeds)
            for seed in range(SEED, SEED + args.seeds):
                clean = simulate(grey, cfa=cfa, gain=gain, seed=seed, optics="none")
                other = simulate(grey, cfa=cfa, gain=gain, seed=seed + args.seeds, optics="none")
                sim = simulate(grey, cfa=cfa, gain=gain, seed=seed, optics="none", defects=d)
                sim.raw.metadata["opcodes"] = sd.gain_map_opcodes(d, sim.raw.cfa, sim.raw.shape)
                with tempfile.TemporaryDirectory() as tmp:
                    path = Path(tmp) / "gainmap.dng"
                    write_raw(path, sim.raw)
                    raw = read_raw(path)
                    add("defect-free", clisp.process(clean.raw))
                    add("defect-free, other seeds", clisp.process(other.raw))
                    add("clisp", clisp.process(raw))
                    add("clisp --no-opcodes", clisp.process(raw, opcodes=False))
                    if cfa == "bayer":
                        add("rawpy (LibRaw)", rawpy_linear(path))
                        add("rawpy, defect-free", rawpy_linear_raw(clean.raw))
            print(f"{cfa} gain {gain:g}, {args.seeds} seeds: defect-free corner/centre luminance "
                  f"{ratio_of(sums['defect-free']):.4f}")
            for name, got in sums.items():
                if name in ("defect-free", "rawpy, defect-free"):
                    continue
                base = sums["rawpy, defect-free" if name.startswith("rawpy") else "defect-free"]
                de = max(ciede2000((c * (b @ LUMA) / (c @ LUMA))[None, None], b[None, None], clip=False)
                         for c, b in zip(got[:4], base[:4]))
                print(f"{cfa} gain {gain:g} {name:<26} corner/centre luminance {ratio_of(got):.4f} "
                      f"({100 * (ratio_of(got) / ratio_of(base) - 1):+.2f} % against the defect-free raw), corner "
                      f"colour CIEDE2000 {de:.2f}")


def add_colours(sums: dict[str, np.ndarray], name: str, out: np.ndarray, weight: float) -> None:
    """Add ``weight`` times ``out``'s corner_colours to sums[name]."""
    sums[name] = sums.get(name, 0.0) + weight * corner_colours(out)


def ratio_of(colours: np.ndarray) -> float:
    """Mean of the 4 corners' luminance over the centre's, of corner_colours' (5, 3) rows."""
    return float(np.mean(colours[:4] @ LUMA) / (colours[4] @ LUMA))


def rawpy_linear(path: Path) -> np.ndarray:
    """rawpy's linear sRGB of a DNG: postprocess with the camera white balance, no auto-bright,
    linear gamma, 16 bit (LibRaw applies no opcode)."""
    import rawpy
    with rawpy.imread(str(path)) as raw:
        rgb = raw.postprocess(use_camera_wb=True, no_auto_bright=True, gamma=(1, 1), output_bps=16,
                              output_color=rawpy.ColorSpace.sRGB, user_flip=0)
    return rgb.astype(np.float64) / 65535.0


def rawpy_linear_raw(raw) -> np.ndarray:
    import tempfile
    from clisp.io.rawfile import write_raw
    with tempfile.TemporaryDirectory() as tmp:
        write_raw(Path(tmp) / "free.dng", raw)
        return rawpy_linear(Path(tmp) / "free.dng")


def corner_colours(img: np.ndarray) -> np.ndarray:
    """(5, 3): the mean colours of the 4 corner patches, then the centre's; patches of 1/8 of each
    side, 8 px in from the edges."""
    h, w = img.shape[:2]
    ph, pw = h // 8, w // 8
    def patch(y, x):
        return img[y:y + ph, x:x + pw].reshape(-1, 3).mean(axis=0)
    return np.array([patch(8, 8), patch(8, w - pw - 8), patch(h - ph - 8, 8), patch(h - ph - 8, w - pw - 8),
                     patch(h // 2 - ph // 2, w // 2 - pw // 2)])


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    toolkit.add_data_option(p)
    p.add_argument("--sets", type=lambda s: s.split(","), default=["kodak", "mcmaster"],
                   help="kodak, mcmaster (the judges); deadleaves, deadleaves-full, textured, textured-coarse, textured-smooth (made in code: the sets to tune on)")
    p.add_argument("--cfa", type=lambda s: s.split(","), default=["lms", "bayer"])
    p.add_argument("--gains", type=lambda s: [float(v) for v in s.split(",")], default=[1.0, 16.0])
    p.add_argument("--cases", type=lambda s: s.split(","), default=list(CASES))
    p.add_argument("--subset", type=int, default=1, help="every Nth image of each set")
    p.add_argument("--frames", type=int, default=16, help="dark or flat frames the corrected runs average")
    p.add_argument("--csv", type=Path, default=None)
    p.add_argument("--results", type=Path, default=None, help="rewrite the bench_sensor block of this Markdown file")
    p.add_argument("--tune", action="store_true")
    for name in TUNED:
        p.add_argument("--" + name.replace("_", "-"), type=lambda s: [float(v) for v in s.split(",")], default=None,
                       help=f"{CONSTANT_HELP[name]} (default: the stage's {name.upper()})")
    p.add_argument("--false-positives", action="store_true")
    p.add_argument("--gainmap-flatness", action="store_true")
    p.add_argument("--size", type=toolkit.parse_size, default=(1536, 1024), help="the grey field's WxH")
    p.add_argument("--seeds", type=int, default=1, help="noise seeds the grey field's colours are averaged over")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.tune:
        tune(args)
        return 0
    if args.false_positives:
        false_positives(args)
        return 0
    if args.gainmap_flatness:
        gainmap_flatness(args)
        return 0
    rows = study(args)
    text = "\n".join(summary(rows))
    print(text)
    if args.csv:
        toolkit.write_csv(rows, args.csv)
    if args.results:
        header = (f"Measured with `python tools/bench_sensor.py {' '.join(sys.argv[1:])}` "
                  f"({len(rows)} runs).\n\n")
        toolkit.update_results(args.results, header + text, "bench_sensor")
    return 0


if __name__ == "__main__":
    sys.exit(main())
