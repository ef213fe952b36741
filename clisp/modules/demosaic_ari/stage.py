"""ARI Bayer demosaic (adaptive residual interpolation; Monno, Kiku, Tanaka, Okutomi, ICIP 2015 /
Sensors 2017) as a Stage: the OpenCL port of ``reference.demosaic_ari`` (float64 NumPy, the
definition of correct; its module doc describes the algorithm). Kernels: ``demosaic_ari.cl`` beside
this file, and the box filter shared in clisp/modules/common (``enqueue_box``).

Input: a white-balanced Bayer mosaic window, H x W float32 (linear, nominally [0, 1]; nothing is
clipped, so values above 1 and below 0 pass through the algebra), any of the four phases. Output:
R, G, B planes of the window less ``halo`` on every side, 3 x (H - 2 halo) x (W - 2 halo) on the
device, in the mosaic's units. ``reference()`` is ``reference.demosaic_ari(window, phase,
green_iterations, chroma_iterations, clip=None)`` cropped by the halo (the reference mirrors at the
window's border; the device never does: it is valid-only, and the halo is the formal support of the
chain, so the two agree on the whole output).

Units: the device scales the mosaic by ``SCALE`` (255) once (``ari_scale``) and the output back by
1 / SCALE, so the reference's constants (``ARI_EPS``, ``ARI_RMSE_FLOOR``, ``WEIGHT_REG``, ``CRIT_REG``,
``CRIT_FLOOR``, in 8-bit units) apply unchanged, in float32. They reach the kernels as defines with the site codes and
each kernel's modes (``program_defines``); every kernel is launched by name (``Runtime.launch_named``).

Schedule, halo derivation, accuracy against the reference and measured history: README.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...cfa import CFA
from ...errors import ClispError
from ...engine.profile import stage_label
from ...engine.runtime import DeviceImage, Runtime
from .reference import (ARI_EPS, ARI_RMSE_FLOOR, CRIT_FLOOR, CRIT_REG, CRITERION_RADIUS, CRITERION_SIGMA, KINDS,
                        LAPLACIAN, PHASES, RB_KINDS, SCALE, STEPS, WEIGHT_REG, ari_window, demosaic_ari, gaussian_taps)
from ...engine.stage import Stage
from ..demosaic_malvar.stage import channel_order, check_bayer
from ..common.box import enqueue_box

SITE_R, SITE_B, SITE_C, SITE_G = 0, 1, 2, 3
"""Site codes of the kernels (R, B, chroma = R or B, G; demosaic_ari.cl's ari_site)."""
LAPLACIAN_RADIUS = len(LAPLACIAN) // 2
"""MLRI's Laplacian [-1, 0, 2, 0, -1] along the direction reads 2 px each way."""
CONSTANTS = {"ARI_EPS": ARI_EPS, "ARI_RMSE_FLOOR": ARI_RMSE_FLOOR, "ARI_WEIGHT_REG": WEIGHT_REG,
             "ARI_CRIT_REG": CRIT_REG, "ARI_CRIT_FLOOR": CRIT_FLOOR,
             "SITE_R": SITE_R, "SITE_B": SITE_B, "SITE_C": SITE_C, "SITE_G": SITE_G}
"""Defines of every program: the reference's constants (8-bit units; float32 literals in the kernels)
and the site codes."""
MODES = {
    "ari_scale": (),
    "ari_green_start": (),
    "ari_along_moments": ("ARI_DIR", "ARI_MLRI", "ARI_PAIR", "ARI_R"),
    "ari_across_coefficients": ("ARI_DIR", "ARI_MLRI", "ARI_PAIR", "ARI_R", "ARI_SET", "ARI_FIT"),
    "ari_box_apply": ("ARI_DIR", "ARI_PAIR", "ARI_R"),
    "ari_green_residual": (),
    "ari_err_terms": ("ARI_SY", "ARI_SX", "ARI_REGION"),
    "ari_gauss_x": ("ARI_REGION",),
    "ari_gauss_y": ("ARI_REGION",),
    "ari_select": (),
    "ari_green_merge": (),
    "ari_chroma_start": ("ARI_KNOWN", "ARI_TARGET"),
    "ari_chroma_residual": ("ARI_KNOWN", "ARI_TARGET"),
    "ari_diag_coefficients": ("ARI_MLRI", "ARI_P", "ARI_Q", "ARI_LS", "ARI_KNOWN"),
    "ari_diag_apply": ("ARI_P", "ARI_Q"),
    "ari_rb_merge": (),
    "ari_final": (),
}
"""Kernel -> the compile-time modes (integer defines) it reads; demosaic_ari.cl's header says what
each mode means."""
ALL_MODES = tuple(sorted({mode for modes in MODES.values() for mode in modes}))


def program_defines(kernel_name: str, modes: dict[str, int]) -> dict[str, object]:
    """The defines of the program that runs ``kernel_name`` in ``modes``: CONSTANTS, exactly the modes
    the kernel reads (any missing or other one is a ClispError), 0 for the modes it does not read,
    and ARI_WITH_<kernel> for the kernels the program holds: those that read the same modes (the
    nine mode-free kernels share one program, a mode combination of ari_gauss_x and _y one).

    A run builds about 140 programs (radii, directions and sites are modes). Each held all 17
    kernels before, and PoCL compiles every kernel of a program when its binary is asked for
    (clisp.engine.programs): a first run of ``--preset best`` on a 0.26 MP raw took 187 s on 2
    cores with empty caches, against 96 s when only launched kernels were compiled."""
    reads = MODES[kernel_name]
    if set(modes) != set(reads):
        raise ClispError(f"demosaic_ari.cl {kernel_name} reads the modes {sorted(reads)}, got {sorted(modes)}")
    held = {f"ARI_WITH_{name}": 1 for name, its in MODES.items() if its == reads}
    return {**CONSTANTS, **dict.fromkeys(ALL_MODES, 0), **modes, **held}


def _gauss_weights() -> tuple[float, float, float]:
    """The criterion's Gaussian taps at offsets 0, 1, 2 (ari_gauss_x / _y's k0, k1, k2)."""
    k = gaussian_taps(CRITERION_RADIUS, CRITERION_SIGMA)
    return float(k[2]), float(k[3]), float(k[4])


# ------------------------------------------------------------------------------------ margins

def _window(kind: str, d: str, along: int, across: int) -> tuple[int, int]:
    """Pixel radii (ry, rx) of a box window (h, v) or the (p, q) lattice radii of a diagonal one."""
    _, a, b = ari_window(kind, d, along, across)
    return a, b


def _fit_radius(kind: str, d: str, along: int, across: int) -> tuple[int, int]:
    """(y, x) read radius of one guided filter (window sums + coefficient sums, + the Laplacian)."""
    lap = LAPLACIAN_RADIUS if kind == "mlri" else 0
    if d in ("d1", "d2"):
        p, q = _window(kind, d, along, across)
        r = 2 * (p + q) + lap
        return r, r
    ry, rx = _window(kind, d, along, across)
    return (2 * ry + lap, 2 * rx) if d == "v" else (2 * ry, 2 * rx + lap)


def _chain_margin(source: int, guide: int, kind: str, d: str, radii: tuple[int, int], iterations: int
                  ) -> tuple[int, int]:
    """Margin (y, x) of the selected estimate of one (direction, kind) chain: its lines start one
    step along d inside ``source`` (the margin of the samples), each iteration's fit reads its radius
    around max(guide, lines), the new lines and the criterion terms read 1 along d around the fit,
    the criterion's Gaussian 2 more (the rules the enqueue follows, checked there)."""
    sy, sx = (abs(v) for v in STEPS[d])
    (along, across) = radii
    my, mx = source + sy, source + sx
    est = (0, 0)
    for _ in range(iterations):
        fy, fx = _fit_radius(kind, d, along, across)
        ty, tx = max(my, guide) + fy, max(mx, guide) + fx
        est = (max(est[0], ty + sy + CRITERION_RADIUS), max(est[1], tx + sx + CRITERION_RADIUS))
        my, mx = ty + sy, tx + sx
        along, across = along + 1, across + 1
    return est


def ari_halo(green_iterations: int, chroma_iterations: int) -> int:
    """The stage's halo in pixels: the formal support of the ARI chain, from the margin rules that the
    enqueue follows (and checks). Closed form, N = ``green_iterations``, M = ``chroma_iterations``:
    3 + N (N + 10) + 2 M^2 + 7 M + 2 + M^2 + 6 M + 3 (121 px for (5, 2); README.md derives it)."""
    green = max(max(_chain_margin(0, 0, kind, d, KINDS[kind], green_iterations))
                for d in ("h", "v") for kind in KINDS)
    step2 = max(max(_chain_margin(0, green, kind, d, RB_KINDS[kind], chroma_iterations))
                for d in ("d1", "d2") for kind in KINDS)
    return max(max(_chain_margin(step2, green, kind, d, RB_KINDS[kind], chroma_iterations))
               for d in ("h", "v") for kind in KINDS)


# ------------------------------------------------------------------------------------ device views

@dataclass(frozen=True)
class _View:
    """Plane ``plane`` of ``image``, whose pixel (0, 0) is pixel (my, mx) of the stage's input window
    (the margin; an image spans the window less its margin on every side)."""

    image: DeviceImage
    my: int
    mx: int
    plane: int = 0

    def named(self, name: str, my: int, mx: int, hy: int = 0, hx: int = 0, planes: bool = False
              ) -> dict[str, object]:
        """The view as the kernel input ``name`` of an output at margin (my, mx) that reads up to
        (hy, hx) pixels around each output pixel: the arguments ``name`` (the buffer), ``name_base``
        (the element at output pixel (0, 0)), ``name_pitch`` (elements per row) and, with ``planes``,
        ``name_plane`` (elements per plane). Checks that the reads stay inside the image."""
        if my - hy < self.my or mx - hx < self.mx:
            raise ClispError(f"ARI: a read at margin ({my}, {mx}) +- ({hy}, {hx}) leaves an image of "
                             f"margin ({self.my}, {self.mx})")
        img = self.image
        plane = img.height * img.width
        base = self.plane * plane + (my - self.my) * img.width + (mx - self.mx)
        args: dict[str, object] = {name: img.buffer, f"{name}_base": base, f"{name}_pitch": img.width}
        if planes:
            args[f"{name}_plane"] = plane
        return args


def _estimates(ests: list[_View], my: int, mx: int) -> dict[str, object]:
    """The four (direction, kind) estimates as the merge kernels' inputs est0..est3 (with plane strides)."""
    args: dict[str, object] = {}
    for k, est in enumerate(ests):
        args.update(est.named(f"est{k}", my, mx, planes=True))
    return args


def _output(image: DeviceImage) -> dict[str, object]:
    """A kernel's output arguments: ``out``, its width ``w`` and height ``h`` (the kernels take their
    coordinates from common.h's inward_id: one command per launch)."""
    return {"out": image, "w": image.width, "h": image.height}


class _Chain:
    """One enqueue: the runtime, the input window size and the CFA parity."""

    def __init__(self, rt: Runtime, height: int, width: int, r_site: tuple[int, int]):
        self.rt, self.h, self.w, self.r_site = rt, height, width, r_site

    def new(self, channels: int, my: int, mx: int) -> DeviceImage:
        """A pooled image of ``channels`` planes spanning the window less margin (my, mx) on every side."""
        h, w = self.h - 2 * my, self.w - 2 * mx
        if h < 1 or w < 1:
            raise ClispError(f"ARI: a {self.h} x {self.w} window is too small for margin ({my}, {mx})")
        return self.rt.acquire(channels, h, w)

    def parity(self, my: int, mx: int) -> dict[str, int]:
        """The arguments py, px: the CFA parities of an output grid at margin (my, mx)."""
        return {"py": (my + self.r_site[0]) & 1, "px": (mx + self.r_site[1]) & 1}

    def launch(self, kernel_name: str, out: DeviceImage, args: dict[str, object], **modes: int) -> None:
        """Enqueue ``kernel_name`` of demosaic_ari.cl, compiled with ``modes``, over exactly the pixels
        of ``out`` (one plane), its arguments by name (Runtime.launch_named checks them)."""
        self.rt.launch_named("demosaic_ari", kernel_name, out.width, out.height, args,
                             program_defines(kernel_name, modes), inward=True)

    def release(self, *images: DeviceImage | None) -> None:
        """Return the images (None: skipped) to the pool."""
        for image in images:
            if image is not None:
                self.rt.release(image)


def _margin(views: list[_View], hy: int, hx: int) -> tuple[int, int]:
    """Smallest output margin at which a kernel reading (hy, hx) around each pixel can read ``views``."""
    return max(v.my for v in views) + hy, max(v.mx for v in views) + hx


# ------------------------------------------------------------------------------------ the stage

@dataclass
class DemosaicARI(Stage):
    """H x W white-balanced Bayer mosaic -> (H - 2 halo) x (W - 2 halo) x 3 camera RGB (ARI; module doc).

    green_iterations   ARI step 1 iterations per direction and kind (the reference's default is 11;
                       5 keeps most of the gain at less than half the halo and time)
    chroma_iterations  steps 2 and 3 iterations
    """

    cfa: CFA
    green_iterations: int = 5
    chroma_iterations: int = 2
    name = "demosaic_ari"
    cfa_kinds = ("bayer",)
    in_channels = 1
    out_channels = 3

    def __post_init__(self) -> None:
        check_bayer(self.cfa, "the ARI demosaic")
        if self.green_iterations < 1 or self.chroma_iterations < 1:
            raise ClispError(f"ARI needs at least one iteration per step, got green {self.green_iterations}, "
                             f"chroma {self.chroma_iterations}")

    @property
    def halo(self) -> int:
        return ari_halo(self.green_iterations, self.chroma_iterations)

    @property
    def bytes_per_pixel(self) -> float:
        """Device bytes per input pixel, 96 float32 planes: covers what one enqueue creates from an
        empty pool (at most 92 planes metered on large windows; README.md). At the peak of step 1 the
        mosaic, the start lines, the estimates of finished chains, the current lines and estimate and
        12 coefficient planes with their two box passes are alive, and the pool's buffers of the other
        (margin-dependent) sizes stay allocated beside them."""
        return 4.0 * 96

    def phase(self, origin: tuple[int, int]) -> str:
        """The Bayer phase name of a window whose pixel (0, 0) is image pixel ``origin``, the channels
        read by their roles (clisp.cfa CFA.bayer_roles: L, M, S as R, G, B on lms-bayer; M, L, S on
        ``ML/LS``)."""
        return self.cfa.bayer_phase(origin)

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        out = demosaic_ari(np.asarray(x, dtype=np.float64), self.phase(origin), self.green_iterations,
                                    self.chroma_iterations, clip=None)
        h = self.halo
        return channel_order(out[h:out.shape[0] - h, h:out.shape[1] - h], self.cfa)

    # -- OpenCL ------------------------------------------------------------------------------
    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        if src.channels != 1 or np.dtype(src.dtype) != np.float32:
            raise ClispError(f"the ARI demosaic takes a 1-plane float32 mosaic, got {src.channels} x {src.dtype}")
        phase = self.phase(origin)
        r_site = PHASES[phase]
        c = _Chain(rt, src.height, src.width, r_site)
        raw_img = c.new(1, 0, 0)
        c.launch("ari_scale", raw_img, {**_View(src, 0, 0).named("src", 0, 0), **_output(raw_img),
                                        "scale": SCALE})
        raw = _View(raw_img, 0, 0)

        stage_label(f"{self.name} 1 green")
        ests = {}
        for d in ("h", "v"):
            sy, sx = STEPS[d]
            my, mx = _margin([raw], sy, sx)
            start = c.new(2, my, mx)
            c.launch("ari_green_start", start, {**raw.named("raw", my, mx, sy, sx), **_output(start), "sy": sy,
                                                "sx": sx, **c.parity(my, mx)})
            for kind in KINDS:
                ests[d, kind] = self._green_chain(c, raw, _View(start, my, mx), d, kind)
            c.release(start)
        green = self._green_merge(c, raw, list(ests.values()))
        for est in ests.values():
            c.release(est.image)

        # step 2: R at B, B at R along the diagonals, statistics over the chroma sites
        stage_label(f"{self.name} 2 diagonals")
        ests = [self._chroma_chain(c, green, [(raw, SITE_R, SITE_B), (raw, SITE_B, SITE_R)], d, kind, True)
                for d in ("d1", "d2") for kind in KINDS]
        rb = self._rb_merge(c, ests, raw)
        # step 3: R and B at the G sites along rows and columns, statistics over every pixel
        stage_label(f"{self.name} 3 G sites")
        rb_r, rb_b = _View(rb.image, rb.my, rb.mx, 0), _View(rb.image, rb.my, rb.mx, 1)
        ests = [self._chroma_chain(c, green, [(rb_r, SITE_C, SITE_G), (rb_b, SITE_C, SITE_G)], d, kind, False)
                for d in ("h", "v") for kind in KINDS]
        out = self._final(c, ests, rb, green)
        c.release(raw_img, rb.image, green.image)
        stage_label(self.name)
        if (out.my, out.mx) != (self.halo, self.halo):
            raise AssertionError(f"ARI: the chain ends at margin ({out.my}, {out.mx}), halo {self.halo}")
        return out.image

    # -- step 1 ------------------------------------------------------------------------------
    def _green_chain(self, c: _Chain, raw: _View, start: _View, d: str, kind: str) -> _View:
        """One (direction, kind) chain of step 1; returns the estimate image (planes G line, chroma
        line, criterion) of the selected iterations."""
        mlri = kind == "mlri"
        sy, sx = STEPS[d]
        along, across = KINDS[kind]
        g, cl = _View(start.image, start.my, start.mx, 0), _View(start.image, start.my, start.mx, 1)
        lines_img: DeviceImage | None = None
        est: _View | None = None
        for _ in range(self.green_iterations):
            coef, margin = self._fit_coefficients(c, cl, g, d, mlri, along, across, pair=True)
            t, ty, tx = self._box_apply(c, coef, margin, d, along, across, cl, g, True)
            tg, tc = _View(t, ty, tx, 0), _View(t, ty, tx, 1)
            # the new lines, and the criterion of this iteration
            ny, nx = ty + abs(sy), tx + abs(sx)
            new = c.new(2, ny, nx)
            c.launch("ari_green_residual", new, {
                **raw.named("raw", ny, nx, sy, sx), **tg.named("tg", ny, nx, sy, sx),
                **tc.named("tc", ny, nx, sy, sx), **_output(new), "sy": sy, "sx": sx, **c.parity(ny, nx)})
            crit = self._criterion(c, [(g, tg), (cl, tc)], d, False)
            c.release(t)
            est = self._select(c, crit, _View(new, ny, nx, 0), _View(new, ny, nx, 1), est)
            c.release(lines_img)
            lines_img = new
            g, cl = _View(new, ny, nx, 0), _View(new, ny, nx, 1)
            along, across = along + 1, across + 1
        c.release(lines_img)
        return est

    def _criterion(self, c: _Chain, errs: list[tuple[_View, _View]], d: str, region: bool) -> _View:
        """Smoothed criterion terms (planes c, g) of two fits (u - t) along d (ari_err_terms, ari_gauss_x/y)."""
        sy, sx = STEPS[d]
        views = [v for pair in errs for v in pair]
        ey, ex = _margin(views, abs(sy), abs(sx))
        terms = c.new(2, ey, ex)
        (u1, t1), (u2, t2) = errs
        reach = (ey, ex, abs(sy), abs(sx))
        c.launch("ari_err_terms", terms, {**u1.named("u1", *reach), **t1.named("t1", *reach),
                                          **u2.named("u2", *reach), **t2.named("t2", *reach), **_output(terms),
                                          **c.parity(ey, ex)},
                 ARI_SY=sy, ARI_SX=sx, ARI_REGION=int(region))
        r = CRITERION_RADIUS
        k0, k1, k2 = _gauss_weights()
        gx = c.new(3 if region else 2, ey, ex + r)
        tv = _View(terms, ey, ex)
        c.launch("ari_gauss_x", gx, {**tv.named("src", ey, ex + r, 0, r, planes=True), **_output(gx),
                                     "k0": k0, "k1": k1, "k2": k2, **c.parity(ey, ex + r)},
                 ARI_REGION=int(region))
        c.release(terms)
        gy = c.new(2, ey + r, ex + r)
        xv = _View(gx, ey, ex + r)
        c.launch("ari_gauss_y", gy, {**xv.named("src", ey + r, ex + r, r, 0, planes=True), **_output(gy),
                                     "k0": k0, "k1": k1, "k2": k2, **c.parity(ey + r, ex + r)},
                 ARI_REGION=int(region))
        c.release(gx)
        return _View(gy, ey + r, ex + r)

    def _select(self, c: _Chain, crit: _View, n1: _View, n2: _View, prev: _View | None) -> _View:
        """ari_select: the running per-pixel best of (n1, n2) by criterion; releases crit and prev."""
        my, mx = _margin([crit, n1, n2] + ([prev] if prev else []), 0, 0)
        out = c.new(3, my, mx)
        p = prev if prev is not None else crit                      # not read on the first iteration
        c.launch("ari_select", out, {**crit.named("crit", my, mx, planes=True), **n1.named("n1", my, mx),
                                     **n2.named("n2", my, mx), **p.named("prev", my, mx, planes=True),
                                     **_output(out), "first": int(prev is None)})
        c.release(crit.image, prev.image if prev else None)
        return _View(out, my, mx)

    def _green_merge(self, c: _Chain, raw: _View, ests: list[_View]) -> _View:
        """ari_green_merge: the full G plane from the four step-1 estimates."""
        my, mx = _margin(ests + [raw], 0, 0)
        m = max(my, mx)
        out = c.new(1, m, m)
        c.launch("ari_green_merge", out, {**_estimates(ests, m, m), **raw.named("raw", m, m),
                                          **_output(out), **c.parity(m, m)})
        return _View(out, m, m)

    # -- steps 2 and 3 -----------------------------------------------------------------------
    def _chroma_chain(self, c: _Chain, guide: _View, planes: list[tuple[_View, int, int]], d: str, kind: str,
                      diagonal: bool) -> _View:
        """One (direction, kind) chain of step 2 (``diagonal``) or 3 for the two planes (source,
        known sites, target sites); returns the estimate image (planes R, B, criterion)."""
        sy, sx = STEPS[d]
        along, across = RB_KINDS[kind]
        cur = []
        for src, known, target in planes:
            my, mx = _margin([src], abs(sy), abs(sx))
            img = c.new(1, my, mx)
            c.launch("ari_chroma_start", img, {**src.named("src", my, mx, abs(sy), abs(sx)),
                                               **_output(img), "sy": sy, "sx": sx,
                                               **c.parity(my, mx)},
                     ARI_KNOWN=known, ARI_TARGET=target)
            cur.append(_View(img, my, mx))
        est: _View | None = None
        for _ in range(self.chroma_iterations):
            ts, news = [], []
            for (src, known, target), x in zip(planes, cur):
                t = (self._diag_fit if diagonal else self._box_fit)(c, guide, x, d, kind, along, across, known)
                ts.append(t)
                ny, nx = _margin([t, src], abs(sy), abs(sx))
                new = c.new(1, ny, nx)
                c.launch("ari_chroma_residual", new, {
                    **src.named("src", ny, nx, abs(sy), abs(sx)), **t.named("t", ny, nx, abs(sy), abs(sx)),
                    **_output(new), "sy": sy, "sx": sx, **c.parity(ny, nx)},
                    ARI_KNOWN=known, ARI_TARGET=target)
                news.append(_View(new, ny, nx))
            crit = self._criterion(c, [(cur[0], ts[0]), (cur[1], ts[1])], d, diagonal)
            c.release(*(t.image for t in ts), *(x.image for x in cur))
            est = self._select(c, crit, news[0], news[1], est)
            cur = news
            along, across = along + 1, across + 1
        c.release(*(x.image for x in cur))
        return est

    def _diag_fit(self, c: _Chain, guide: _View, x: _View, d: str, kind: str, along: int, across: int,
                  known: int) -> _View:
        """Step 2's weighted guided filter of x against the guide over a diagonal window."""
        mlri = kind == "mlri"
        p, q = _window(kind, d, along, across)
        reach = p + q + (LAPLACIAN_RADIUS if mlri else 0)
        my, mx = _margin([guide, x], reach, reach)
        coef = c.new(3, my, mx)
        c.launch("ari_diag_coefficients", coef, {**guide.named("xs", my, mx, reach, reach),
                                                 **x.named("ys", my, mx, reach, reach), **_output(coef),
                                                 **c.parity(my, mx)},
                 ARI_MLRI=int(mlri), ARI_P=p, ARI_Q=q, ARI_LS=STEPS[d][1], ARI_KNOWN=known)
        r = p + q
        t = c.new(1, my + r, mx + r)
        cv = _View(coef, my, mx)
        c.launch("ari_diag_apply", t, {**cv.named("coef", my + r, mx + r, r, r, planes=True),
                                       **guide.named("xs", my + r, mx + r), **_output(t)},
                 ARI_P=p, ARI_Q=q)
        c.release(coef)
        return _View(t, my + r, mx + r)

    def _box_fit(self, c: _Chain, guide: _View, x: _View, d: str, kind: str, along: int, across: int,
                 known: int) -> _View:
        """Step 3's weighted guided filter of x against the guide over a box window (statistics over
        every pixel, MLRI's Laplacian moments over the chroma sites)."""
        coef, margin = self._fit_coefficients(c, guide, x, d, kind == "mlri", along, across, pair=False)
        t, ty, tx = self._box_apply(c, coef, margin, d, along, across, guide, x, False)
        return _View(t, ty, tx)

    def _fit_coefficients(self, c: _Chain, x: _View, y: _View, d: str, mlri: bool, along: int, across: int,
                          pair: bool) -> tuple[DeviceImage, tuple[int, int]]:
        """The weighted fits' coefficients over windows of 2 along + 1 pixels along the lines and
        2 across + 1 across them: the moments along the lines (ari_along_moments), then across
        them with the fits (ari_across_coefficients). ``pair`` (step 1): the four fits of line set
        x fit into planes 0-5 (R lines) and 6-11 (B lines), G from chroma then chroma from G; else
        (step 3) the one fit of y from x, 3 planes. Releases the moments; returns the coefficients
        and their margin."""
        dirn = 0 if d == "h" else 1
        lap = LAPLACIAN_RADIUS if mlri else 0
        ay, ax = (0, along + lap) if d == "h" else (along + lap, 0)
        my, mx = _margin([x, y], ay, ax)
        mom = c.new((12 if pair else 9) if mlri else 6, my, mx)
        c.launch("ari_along_moments", mom, {**x.named("xs", my, mx, ay, ax), **y.named("ys", my, mx, ay, ax),
                                            **_output(mom), **c.parity(my, mx)},
                 ARI_DIR=dirn, ARI_MLRI=int(mlri), ARI_PAIR=int(pair), ARI_R=along)
        cy, cx = (across, 0) if d == "h" else (0, across)
        coef = c.new(12 if pair else 3, my + cy, mx + cx)
        fits = [(line_set, fit) for line_set in (0, 1) for fit in (0, 1)] if pair else [(0, 0)]   # step 3: unread
        for line_set, fit in fits:
            c.launch("ari_across_coefficients", coef, {
                "rows": mom, "rows_pitch": mom.width, "rows_plane": mom.width * mom.height,
                **x.named("xs", my + cy, mx + cx, cy, cx), **y.named("ys", my + cy, mx + cx, cy, cx),
                **_output(coef), "out_base": (6 * line_set + 3 * fit) * coef.width * coef.height,
                **c.parity(my + cy, mx + cx)},
                ARI_DIR=dirn, ARI_MLRI=int(mlri), ARI_PAIR=int(pair), ARI_R=across, ARI_SET=line_set, ARI_FIT=fit)
        c.release(mom)
        return coef, (my + cy, mx + cx)

    def _box_apply(self, c: _Chain, coef: DeviceImage, margin: tuple[int, int], d: str, along: int,
                   across: int, x: _View, y: _View, pair: bool) -> tuple[DeviceImage, int, int]:
        """Coefficient sums along the lines (the shared box filter, every plane), then across them
        fused with the tentative estimates (ari_box_apply); releases coef. Returns (t, margin y, x)."""
        dirn = 0 if d == "h" else 1
        sums = enqueue_box(c.rt, coef, 0, along, release_src=True) if d == "h" else \
            enqueue_box(c.rt, coef, along, 0, release_src=True)
        sy, sx = (margin[0], margin[1] + along) if d == "h" else (margin[0] + along, margin[1])
        ty, tx = (sy + across, sx) if d == "h" else (sy, sx + across)
        t = c.new(2 if pair else 1, ty, tx)
        sv = _View(sums, sy, sx)
        hy, hx = (across, 0) if d == "h" else (0, across)
        c.launch("ari_box_apply", t, {**sv.named("coef", ty, tx, hy, hx, planes=True), **x.named("xs", ty, tx),
                                      **y.named("ys", ty, tx), **_output(t), **c.parity(ty, tx)},
                 ARI_DIR=dirn, ARI_PAIR=int(pair), ARI_R=across)
        c.release(sums)
        return t, ty, tx

    def _rb_merge(self, c: _Chain, ests: list[_View], raw: _View) -> _View:
        """ari_rb_merge: R and B planes after step 2 (the mosaic's samples and step 2's estimates);
        releases the estimates."""
        my, mx = _margin(ests + [raw], 0, 0)
        out = c.new(2, my, mx)
        c.launch("ari_rb_merge", out, {**_estimates(ests, my, mx), **raw.named("raw", my, mx), **_output(out),
                                       **c.parity(my, mx)})
        c.release(*(e.image for e in ests))
        return _View(out, my, mx)

    def _final(self, c: _Chain, ests: list[_View], rb: _View, green: _View) -> _View:
        """ari_final: the output planes R, G, B in the mosaic's units from step 3's estimates, step 2's
        R and B and the G plane, each role written to its channel's plane (CFA.bayer_roles); releases
        the estimates."""
        my, mx = _margin(ests + [rb, green], 0, 0)
        out = c.new(3, my, mx)
        r, g, b = self.cfa.bayer_roles           # the output plane of each role: the CFA's channel order
        c.launch("ari_final", out, {**_estimates(ests, my, mx), **rb.named("rb", my, mx, planes=True),
                                    **green.named("green", my, mx), **_output(out), **c.parity(my, mx),
                                    "scale": 1.0 / SCALE, "plane_r": r, "plane_g": g, "plane_b": b})
        c.release(*(e.image for e in ests))
        return _View(out, my, mx)
