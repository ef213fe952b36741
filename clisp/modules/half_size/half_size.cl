/* Half-size binning (--half-size); NumPy reference and the rule in clisp/modules/half_size/stage.py,
 * one kernel per step with the same name.
 *
 * Defines from the host: RAW_T (input mosaic type: ushort or float); HS_BLOCK (2: mosaic pixels per
 * output pixel); HS_SIDE (HS_BLOCK + 2 r: the window side, r the stage's halo); HS_PHASES (block
 * phases per axis: CFA period / HS_BLOCK); the fused per-pixel stages that follow (HalfSize.fuse):
 * HS_CAP (1: a highlight clamp), ENCODE_SRGB (1: the sRGB tone curve, with srgb.h and the SRGB_* defines
 * prepended by the host), QUANTIZE (1: 16-bit codes); INTERLEAVED (0: 3 planes, 1: H x W x 3). */

#include "store.h"

/* half_size_bin: output pixel (y, x) from the HS_SIDE x HS_SIDE window of raw at (HS_BLOCK y,
 * HS_BLOCK x) (its 2 x 2 block at (HS_BLOCK y + r, HS_BLOCK x + r)):
 * out_k = gain_k (sum_p w_k(p) raw(p) - offset_k), w the weights of the block's phase
 * (stage.phase_weights: 1 / count where sample p is of channel k, 0 elsewhere, so sum_p w_k(p) = 1
 * and out_k is the mean of channel k's normalised, white-balanced samples); then, fused: the clamp
 * out_k <- min(out_k, cap_k) (HS_CAP), dst = m out (a fused colour matrix, identity otherwise),
 * the tone curve (ENCODE_SRGB, QUANTIZE). weights: HS_PHASES^2 x 3 x HS_SIDE^2; (block_y, block_x):
 * the phase of output pixel (0, 0)'s block. Halo r; launched over exactly out_w x out_h
 * (launch_exact): no bounds check, so PoCL vectorises it. */
__kernel void half_size_bin(__global const RAW_T *restrict raw, __global out_t *restrict dst,
                            const int raw_w, const int out_w, const int out_h,
                            const int block_y, const int block_x, __constant const float *restrict weights,
                            __constant const float *restrict offset, __constant const float *restrict gain,
                            __constant const float *restrict cap, __constant const float *restrict m)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int phase = ((block_y + y) % HS_PHASES) * HS_PHASES + (block_x + x) % HS_PHASES;
    __constant const float *w = weights + phase * 3 * HS_SIDE * HS_SIDE;
    __global const RAW_T *p = raw + HS_BLOCK * y * raw_w + HS_BLOCK * x;
    float s0 = 0.0f, s1 = 0.0f, s2 = 0.0f;
    #pragma unroll
    for (int dy = 0; dy < HS_SIDE; ++dy) {
        #pragma unroll
        for (int dx = 0; dx < HS_SIDE; ++dx) {
            const float v = (float)p[dy * raw_w + dx];
            const int j = dy * HS_SIDE + dx;
            s0 += w[j] * v;
            s1 += w[HS_SIDE * HS_SIDE + j] * v;
            s2 += w[2 * HS_SIDE * HS_SIDE + j] * v;
        }
    }
    float a = gain[0] * (s0 - offset[0]), b = gain[1] * (s1 - offset[1]), c = gain[2] * (s2 - offset[2]);
#if HS_CAP
    a = a < cap[0] ? a : cap[0];               /* not fmin: PoCL does not vectorise it */
    b = b < cap[1] ? b : cap[1];
    c = c < cap[2] ? c : cap[2];
#endif
    const out_t o0 = STORE(m[0] * a + m[1] * b + m[2] * c);
    const out_t o1 = STORE(m[3] * a + m[4] * b + m[5] * c);
    const out_t o2 = STORE(m[6] * a + m[7] * b + m[8] * c);
    const int i = y * out_w + x;
#if INTERLEAVED
    dst[3 * i] = o0;
    dst[3 * i + 1] = o1;
    dst[3 * i + 2] = o2;
#else
    const int plane = out_w * out_h;
    dst[i] = o0;
    dst[plane + i] = o1;
    dst[2 * plane + i] = o2;
#endif
}
