"""Per-phase linear filters on the raw mosaic (kernels ``linear_filter.cl``: ``phase_filter``, ``phase_filter_px``,
``phase_filter_px8``, ``phase_filter_p4x8``).

Output channel c at a pixel of CFA phase k is ``bias[k, c] + sum_t weights[k, c, t] * raw(tap t)``
over the (2R+1)^2 window; ``support`` marks the taps that can be non-zero (structure of the
demosaic, fixed by the CFA), and only those are computed. Any linear demosaic is such a filter, and so is any chain of linear
per-pixel steps around it: black/white normalisation and WB pass 1 before, the colour matrix and
WB pass 2 after fold into the weights (``fuse``). The fast path runs that whole chain as one kernel.

A filter may also carry its factors: ``basis`` (K, Cd, T), the demosaic's own weights (fixed by the
CFA, so compiled in as literals), and ``mix`` (C, Cd), the per-image matrix applied after it, with
``weights[k] == mix @ basis[k]``. While the basis is channel-pure (demosaic channel d reads only
CFA channel d, as bilinear does) the per-channel normalisation folds into ``mix`` too, and the
kernel computes the demosaic in a few shared sums and the matrix in C*Cd multiplies, instead of
C dense sums over the window (about half the arithmetic for bilinear Bayer).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...cfa import CFA
from ...sim.colorimetry import SRGB_ENCODING, quantize8, quantize16, srgb_encode
from ...engine.runtime import DeviceImage, Runtime, get_runtime, launch_exact
from ...errors import ClispError
from ...engine.stage import Stage, as_f32
from ..colour.stage import ColourMatrix, ToneCurve, eight_per_item, srgb_source


FUSE_TONE_CURVE_PERIOD = 2
"""CFA period whose filters take the tone curve into their store (``fuse``): the per-column kernels
(``phase_filter_px``, and ``phase_filter_px8`` on CPU devices) then encode what they computed
instead of writing linear floats for a tone-curve kernel to read again. The block kernel of
period 4 (LMS) with the curve inside ran at about 105 MP/s against 800 and 270 MP/s for the
filter and the tone-curve kernel apart (PoCL, 24 MP; README.md): period 4 takes it only where
``phase_filter_p4x8`` runs (:func:`tone_in_store`)."""

PAIRS_PERIOD = 4
"""CFA period of kernel ``phase_filter_p4x8``: eight columns per work-item starting on a multiple of
4, so columns j and j + 4 share a phase and each phase is computed once, for two pixels (float2).
On a CPU device it takes the tone curve into its store, which the block kernel could not afford: the
LMS fast preset to 16-bit codes, 12 MP, 70.5 -> 48.4 ms, 8-bit 57.6 -> 45.2, a 0.26 MP call 1.94 ->
1.57 ms, the same codes bit for bit (README.md)."""


def tone_in_store(period: int) -> bool:
    """Whether a filter of CFA ``period`` takes a following tone curve into its store (``fuse``):
    period 2 on every device (``phase_filter_px`` / ``phase_filter_px8``), period 4 on a CPU device,
    where ``phase_filter_p4x8`` runs; elsewhere (a GPU, whose block kernel with the curve inside is
    not measured) the curve stays its own kernel."""
    if period == FUSE_TONE_CURVE_PERIOD:
        return True
    if period != PAIRS_PERIOD:
        return False
    try:
        return eight_per_item(get_runtime())
    except ClispError:                       # no OpenCL device: nothing will run the fused kernel
        return False


def tap_offsets(radius: int) -> np.ndarray:
    """(T, 2) int array of (dy, dx) for the (2R+1)^2 taps in row order (kernel order)."""
    d = np.arange(-radius, radius + 1)
    return np.stack(np.meshgrid(d, d, indexing="ij"), axis=-1).reshape(-1, 2)


def tap_channels(cfa: CFA, radius: int) -> np.ndarray:
    """(P*P, T) CFA channel of each tap around a pixel of each phase k = py * P + px."""
    p = cfa.period
    offsets = tap_offsets(radius)
    ky, kx = np.divmod(np.arange(p * p), p)
    return cfa.pattern[(ky[:, None] + offsets[None, :, 0]) % p, (kx[:, None] + offsets[None, :, 1]) % p]


PER_COLUMN_PERIOD = 2
"""CFA period for which whole-row tiles take kernel ``phase_filter_px`` (one work-item per column)
instead of the block kernel: 13-20 ms against 50-64 ms for 24 MP of bilinear Bayer on PoCL (README.md).
The LMS period 4 would compute four column phases per pixel; it keeps the block kernel."""


PER_COLUMN_GROUP = (128, 1)
"""Work-group of kernel ``phase_filter_px``: one row of 128 columns (12.5-12.8 ms against 15.8-17.0
with 64 columns, 24 MP Bayer on PoCL; README.md). A group one row high also never leaves a ragged
strip of rows, so a band is two launches instead of four."""


def channel_pure(basis: np.ndarray, channels: np.ndarray) -> bool:
    """Whether basis (K, Cd, T) row d reads only taps of CFA channel d (``channels``: (K, T))."""
    d = np.arange(basis.shape[1])
    return bool(np.all((basis == 0) | (channels[:, None, :] == d[None, :, None])))


def literal(value: float) -> str:
    """An OpenCL float literal for ``value`` (float32-rounded, round-trips)."""
    text = repr(float(np.float32(value)))
    return text + "f" if ("." in text or "e" in text) else text + ".0f"


def basis_sum(weights: np.ndarray) -> str:
    """OpenCL expression of sum_t weights[t] * v[t] over the non-zero taps, taps of equal weight
    summed first (bilinear: 0.25f * (v[1] + v[3] + v[5] + v[7]))."""
    groups: dict[float, list[int]] = {}
    for t in np.flatnonzero(weights):
        groups.setdefault(float(np.float32(weights[t])), []).append(int(t))
    terms = []
    for value, taps in groups.items():
        total = " + ".join(f"v[{t}]" for t in taps)
        total = f"({total})" if len(taps) > 1 else total
        terms.append(total if value == 1.0 else f"{literal(value)} * {total}")
    return " + ".join(terms) if terms else "0.0f"


@dataclass
class LinearPhaseFilter(Stage):
    """H x W mosaic -> H x W x n_out; weights (P*P, n_out, T), bias (P*P, n_out); optional sRGB encode
    (``encode``), to codes of ``bits`` (16: uint16, 8: uint8; ``quantize``)."""

    cfa: CFA
    radius: int
    weights: np.ndarray
    bias: np.ndarray
    encode: bool = False
    quantize: bool = False
    interleaved: bool = False
    bits: int = 16
    support: np.ndarray | None = None
    basis: np.ndarray | None = None
    mix: np.ndarray | None = None
    name = "phase_filter"
    in_channels = 1
    out_channels = 3
    writes_into = True

    def __post_init__(self) -> None:
        if self.support is None:
            self.support = self.weights != 0
        if (self.basis is None) != (self.mix is None):
            raise ValueError("basis and mix come together")

    @property
    def factored(self) -> bool:
        """Whether the kernel may compute ``mix @ basis`` instead of the dense weights."""
        return self.basis is not None

    @property
    def out_dtype(self) -> np.dtype:
        if not self.quantize:
            return np.dtype(np.float32)
        return np.dtype(np.uint8 if self.bits == 8 else np.uint16)

    @property
    def halo(self) -> int:
        return self.radius

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        h, w = x.shape
        r = self.radius
        oh, ow = h - 2 * r, w - 2 * r
        p = self.cfa.period
        ys = (np.arange(oh) + origin[0] + r) % p
        xs = (np.arange(ow) + origin[1] + r) % p
        phase = ys[:, None] * p + xs[None, :]
        out = self.bias[phase].astype(np.float64)
        x = x.astype(np.float64)
        for t, (dy, dx) in enumerate(tap_offsets(r)):
            out += self.weights[phase, :, t] * x[r + dy:r + dy + oh, r + dx:r + dx + ow, None]
        if not self.encode:
            return out
        if not self.quantize:
            return srgb_encode(out)
        return quantize8(srgb_encode(out)) if self.bits == 8 else quantize16(srgb_encode(out))

    def __getstate__(self) -> dict:
        """The stage's parameters without the kernel text it caches on first use (``_source``):
        a pickle names the stage (the metering and schedule caches' keys), and must not change
        once it has run."""
        state = dict(vars(self))
        state.pop("_source", None)
        return state

    def generated_source(self) -> str:
        """OpenCL source of ``phase_apply(k, v, o, w, bias)``: one inline function per CFA phase
        summing only the taps in ``support`` (weights read from the constant buffer at literal
        indices). The support depends on the CFA and the demosaic, not on per-image values
        (black level, white balance, matrix), so one compiled program serves every image."""
        n_out = self.weights.shape[1]
        lines = [f"/* generated by clisp: support of {self.name}, {self.weights.shape[0]} phases */"]
        lines += self._phase_functions("float", "phase")
        lines.append(self.row_source())
        if self.cfa.period == 2 and n_out == 3:
            lines.append(self.row8_source())
        if self.cfa.period == PAIRS_PERIOD and n_out == 3:
            lines.append(self.phase2_source())
        return "\n".join(lines)

    def phase2_source(self) -> str:
        """OpenCL source of ``phase2_apply(k, v, o, w, bias)`` for kernel ``phase_filter_p4x8``:
        ``phase_apply``'s sums for two pixels of phase k at once (float2 values and outputs), the
        same terms in the same order."""
        return "\n".join([f"/* generated by clisp: phase2_apply of {self.name} */"]
                         + self._phase_functions("float2", "phase2"))

    def _phase_functions(self, value: str, prefix: str) -> list[str]:
        """``<prefix>_<k>`` per phase k and ``<prefix>_apply(k, v, o, w, bias)`` choosing among them,
        on values of OpenCL type ``value`` (float, or float2 for two pixels of one phase)."""
        n_out, taps = self.weights.shape[1:]
        bias = "bias[{}]" if value == "float" else f"({value})(bias[{{}}])"
        lines = []
        for k in range(self.weights.shape[0]):
            body = []
            for c in range(n_out):
                base = (k * n_out + c) * taps
                terms = [bias.format(k * n_out + c)] + [f"w[{base + t}] * v[{t}]"
                                                        for t in np.flatnonzero(self.support[k, c])]
                body.append(f"    o[{c}] = " + " + ".join(terms) + ";")
            lines.append(f"inline void {prefix}_{k}(const {value} *v, {value} *o, __constant const float *w, "
                         f"__constant const float *bias)\n{{\n" + "\n".join(body) + "\n}")
        cases = " ".join(f"case {k}: {prefix}_{k}(v, o, w, bias); break;" for k in range(self.weights.shape[0]))
        lines.append(f"inline void {prefix}_apply(const int k, const {value} *v, {value} *o, __constant const float *w, "
                     f"__constant const float *bias)\n{{\n    switch (k) {{ {cases} }}\n}}")
        return lines

    def row_source(self) -> str:
        """OpenCL source of ``row_apply(ky, px, v, o, w, bias)`` for kernel ``phase_filter_px``:
        for CFA row ky every column phase j is computed and the one of ``px`` selected. Dense form:
        ``w`` holds the weights as for ``phase_apply``. Factored form: per column phase the basis
        sums (literal weights, taps of equal weight added first), then ``o[c] = bias[k][c] + sum_d
        w[c * Cd + d] * s_d`` with ``w`` holding ``mix``."""
        return self._row_functions(eight=False)

    def row8_source(self) -> str:
        """OpenCL source of ``row_apply8(ky, m1, v, o, w, bias)`` for kernel ``phase_filter_px8``
        (period 2, three outputs): :meth:`row_source`'s sums for eight neighbouring columns at once,
        ``v`` and ``o`` float8 per tap and per output, the column phase 1 in the lanes where the int8
        mask ``m1`` is set. Each lane computes what ``row_apply`` computes for its column, in the
        same order."""
        return self._row_functions(eight=True)

    def _row_functions(self, eight: bool) -> str:
        """:meth:`row_source` (``eight`` False: float values, the column phase ``px``) or
        :meth:`row8_source` (float8 values, the lane mask ``m1``)."""
        p = self.cfa.period
        n_out, taps = self.weights.shape[1:]
        value, fn, apply, phase = (("float8", "row8", "row_apply8", "const int8 m1") if eight
                                   else ("float", "row", "row_apply", "const int px"))
        lines = [(f"/* generated by clisp: {apply} of {self.name}, "
                  f"{'factored (mix @ basis)' if self.factored else 'dense weights'} */")]

        def select(values: list[str]) -> str:
            if eight:                                       # period 2: lanes of phase 1 where m1 is set
                return f"(m1 ? {values[1]} : {values[0]})"
            expr = values[0]
            for j in range(1, p):
                expr = f"(px == {j} ? {values[j]} : {expr})"
            return expr

        def bias(index: int) -> str:
            return f"(float8)(bias[{index}])" if eight else f"bias[{index}]"

        for ky in range(p):
            body = []
            phases = [ky * p + j for j in range(p)]
            if self.factored:
                n_d = self.basis.shape[1]
                for j, k in enumerate(phases):
                    for d in range(n_d):
                        body.append(f"    const {value} s{j}_{d} = {basis_sum(self.basis[k, d])};")
                for d in range(n_d):
                    body.append(f"    const {value} s{d} = " + select([f"s{j}_{d}" for j in range(p)]) + ";")
                for c in range(n_out):
                    terms = [select([bias(k * n_out + c) for k in phases])]
                    terms += [f"w[{c * n_d + d}] * s{d}" for d in range(n_d)]
                    body.append(f"    o[{c}] = " + " + ".join(terms) + ";")
            else:
                for j, k in enumerate(phases):
                    for c in range(n_out):
                        base = (k * n_out + c) * taps
                        terms = [bias(k * n_out + c)] + [f"w[{base + t}] * v[{t}]"
                                                         for t in np.flatnonzero(self.support[k, c])]
                        body.append(f"    const {value} e{j}_{c} = " + " + ".join(terms) + ";")
                for c in range(n_out):
                    body.append(f"    o[{c}] = " + select([f"e{j}_{c}" for j in range(p)]) + ";")
            lines.append(f"inline void {fn}_{ky}({phase}, const {value} *v, {value} *o, "
                         "__constant const float *w, __constant const float *bias)\n{\n"
                         + "\n".join(body) + "\n}")
        arg = phase.split()[-1]
        cases = " ".join(f"case {ky}: {fn}_{ky}({arg}, v, o, w, bias); break;" for ky in range(p))
        lines.append(f"inline void {apply}(const int ky, {phase}, const {value} *v, {value} *o, "
                     f"__constant const float *w, __constant const float *bias)\n{{\n"
                     f"    switch (ky) {{ {cases} }}\n}}")
        return "\n".join(lines)

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int],
                out: DeviceImage | None = None) -> DeviceImage:
        p, r = self.cfa.period, self.radius
        defines = {"CFA_PERIOD": p, "NOUT": self.weights.shape[1], "RADIUS": r,
                   "RAW_T": "ushort" if src.dtype == np.uint16 else "float",
                   "PHASE_Y": (origin[0] + r) % p, "PHASE_X": (origin[1] + r) % p,
                   "ENCODE_SRGB": int(self.encode), "QUANTIZE": int(self.quantize), "CODE_BITS": self.bits,
                   "INTERLEAVED": int(self.interleaved), **SRGB_ENCODING}
        out_h, out_w = self.output_shape(src.height, src.width)
        per_column = p == PER_COLUMN_PERIOD and out_h % p == 0
        eight = per_column and self.interleaved and out_w >= 8 and self.weights.shape[1] == 3 and eight_per_item(rt)
        pairs = p == PAIRS_PERIOD and self.encode and self.interleaved and out_h % p == 0 and out_w % p == 0 \
            and out_w >= 8 and self.weights.shape[1] == 3 and eight_per_item(rt)
        exact = per_column or (out_h % p == 0 and out_w % p == 0)   # no bounds checks: PoCL vectorises
        defines["EXACT"] = int(exact)
        if not hasattr(self, "_source"):
            self._source = (srgb_source(rt) + "\n" if self.encode else "") + self.generated_source()
        name = "phase_filter_px8" if eight else "phase_filter_p4x8" if pairs else \
            "phase_filter_px" if per_column else "phase_filter"
        kernel = rt.kernel("linear_filter", name, defines, self._source)
        dst = out if out is not None else rt.acquire(self.weights.shape[1], out_h, out_w, self.out_dtype)
        w = self.mix if per_column and self.factored else self.weights
        args = (src.buffer, dst.buffer, np.int32(src.width), np.int32(out_w), np.int32(out_h),
                rt.constant(as_f32(w)), rt.constant(as_f32(self.bias)))
        if eight or pairs:
            rt.launch(kernel, -(-out_w // 8), out_h // p, *args)
        elif per_column:
            launch_exact(rt, kernel, out_w, out_h // p, *args, group=PER_COLUMN_GROUP)
        elif exact:
            launch_exact(rt, kernel, out_w // p, out_h // p, *args, inward=True)
        else:
            rt.launch(kernel, -(-out_w // p), -(-out_h // p), *args)
        dst.interleaved = self.interleaved
        return dst

    def with_interleaved_output(self) -> "LinearPhaseFilter":
        return replace(self, interleaved=True)

    def after_affine(self, offset: np.ndarray, scale: np.ndarray) -> "LinearPhaseFilter":
        """This filter applied to ``(raw - offset[c]) * scale[c]``, as one filter on raw."""
        ch = tap_channels(self.cfa, self.radius)                       # (K, T)
        w = self.weights * np.asarray(scale)[ch][:, None, :]           # (K, C, T)
        bias = self.bias - np.einsum("kct,kt->kc", w, np.asarray(offset)[ch])
        basis, mix = self.basis, self.mix
        if basis is not None and channel_pure(basis, ch):               # scale[d] is basis row d's
            mix = self.mix * np.asarray(scale, dtype=np.float64)[None, :basis.shape[1]]
        else:
            basis, mix = None, None
        return replace(self, weights=w, bias=bias, basis=basis, mix=mix)

    def fuse(self, following: Stage) -> Stage | None:
        if self.encode:
            return None
        if isinstance(following, ColourMatrix):
            m = np.asarray(following.matrix, dtype=np.float64)
            mixed = np.repeat(self.support.any(axis=1, keepdims=True), m.shape[0], axis=1)
            return replace(self, weights=np.einsum("ij,kjt->kit", m, self.weights),
                           bias=self.bias @ m.T, support=mixed,
                           mix=None if self.mix is None else m @ self.mix)
        if isinstance(following, ToneCurve) and tone_in_store(self.cfa.period):
            return replace(self, encode=True, quantize=following.quantize, bits=following.bits)
        return None
