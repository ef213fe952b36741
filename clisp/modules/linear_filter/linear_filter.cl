/* Per-phase linear filters on the raw mosaic: the fast demosaic family.
 * Defines from the host: CFA_PERIOD (P), NOUT (output planes), RADIUS (halo R), RAW_T (input type),
 * PHASE_Y/PHASE_X (CFA phase of output pixel (0, 0)), ENCODE_SRGB (0/1), QUANTIZE (0/1: 16-bit out),
 * INTERLEAVED (0: NOUT planes; 1: H x W x NOUT, the host's layout, when this is the last stage).
 * The host also prepends generated code: phase_apply(k, v, o, w, bias) sets o[c] for CFA phase k
 * from the window v[(2R+1)^2], summing only the taps the filter can use (its support, fixed by the
 * CFA and demosaic), so structural zeros cost nothing and per-image weights stay arguments; and
 * row_apply(ky, px, v, o, w, bias), the same for CFA row ky with the column phase px a run-time
 * value (every column phase computed, the right one selected); for period 2 row_apply8, and for
 * period 4 phase2_apply(k, v, o, w, bias), phase_apply for two pixels of phase k as float2. */
#define SIDE (2 * RADIUS + 1)
#define TAPS (SIDE * SIDE)

/* With ENCODE_SRGB the host prepends clisp/modules/colour/srgb.h (encode_srgb, quantize16) and its table;
 * QUANTIZE (define) then writes 16-bit codes instead of float. */
#include "store.h"

/* phase_filter: out_c(y, x) = bias[k][c] + sum_t w[k][c][t] * src(y + dy_t, x + dx_t), k the CFA
 * phase of output pixel (y, x), taps t over the (2R+1)^2 window in row order. Halo RADIUS.
 * One work-item computes one P x P block; both block loops unroll and k is a compile-time
 * constant in each, so phase_apply folds to straight-line code and every weight load is uniform
 * across work-items. w: [P*P][NOUT][TAPS], bias: [P*P][NOUT]. */
__kernel void phase_filter(__global const RAW_T *restrict src, __global out_t *restrict dst,
                           const int in_w, const int out_w, const int out_h,
                           __constant const float *restrict w, __constant const float *restrict bias)
{
#if EXACT          /* blocks tile the output: one command, the last work-group shifted inward (common.h) */
    const int bx = inward_id(0, out_w / CFA_PERIOD - 1) * CFA_PERIOD;
    const int by = inward_id(1, out_h / CFA_PERIOD - 1) * CFA_PERIOD;
#else
    const int bx = get_global_id(0) * CFA_PERIOD;
    const int by = get_global_id(1) * CFA_PERIOD;
    if (bx >= out_w || by >= out_h) return;
#endif
    const int plane = out_w * out_h;
    #pragma unroll
    for (int i = 0; i < CFA_PERIOD; ++i) {
        #pragma unroll
        for (int j = 0; j < CFA_PERIOD; ++j) {
            const int y = by + i;
            const int x = bx + j;
#if !EXACT
            if (y < out_h && x < out_w)
#endif
            {
                float v[TAPS];
                float o[NOUT];
                #pragma unroll
                for (int t = 0; t < TAPS; ++t)
                    v[t] = (float)src[(y + t / SIDE) * in_w + x + t % SIDE];
                phase_apply(((i + PHASE_Y) % CFA_PERIOD) * CFA_PERIOD + (j + PHASE_X) % CFA_PERIOD, v, o, w, bias);
                #pragma unroll
                for (int c = 0; c < NOUT; ++c) {
                    const int index = INTERLEAVED ? (y * out_w + x) * NOUT + c : c * plane + y * out_w + x;
                    dst[index] = STORE(o[c]);
                }
            }
        }
    }
}

/* phase_filter_px: the same filter, one work-item per output column x and CFA_PERIOD rows (the
 * kernel for PoCL: neighbouring work-items read neighbouring raw samples and write neighbouring
 * pixels, so the work-item loop vectorises; the block kernel above strides by P and does not).
 * The row phase is a compile-time constant in each unrolled row, the column phase px a run-time
 * select. Halo RADIUS. Needs out_h a multiple of CFA_PERIOD and no bounds checks (launch_exact).
 * w, bias: as the host's generated row_apply reads them. */
__kernel void phase_filter_px(__global const RAW_T *restrict src, __global out_t *restrict dst,
                              const int in_w, const int out_w, const int out_h,
                              __constant const float *restrict w, __constant const float *restrict bias)
{
    const int x = get_global_id(0);
    const int by = get_global_id(1) * CFA_PERIOD;
    const int px = (x + PHASE_X) & (CFA_PERIOD - 1);      /* CFA_PERIOD a power of two here */
    const int plane = out_w * out_h;
    #pragma unroll
    for (int i = 0; i < CFA_PERIOD; ++i) {
        const int y = by + i;
        float v[TAPS];
        float o[NOUT];
        #pragma unroll
        for (int t = 0; t < TAPS; ++t)
            v[t] = (float)src[(y + t / SIDE) * in_w + x + t % SIDE];
        row_apply((i + PHASE_Y) % CFA_PERIOD, px, v, o, w, bias);
        #pragma unroll
        for (int c = 0; c < NOUT; ++c) {
            const int index = INTERLEAVED ? (y * out_w + x) * NOUT + c : c * plane + y * out_w + x;
            dst[index] = STORE(o[c]);
        }
    }
}

/* phase_filter_px8: phase_filter_px for eight neighbouring columns per work-item, writing H x W x 3
 * (the host's layout), for CPU devices: PoCL turns the per-column kernel's interleaved stores into
 * scattered scalar stores, and the tone curve as a kernel of its own read and wrote every pixel again
 * (clisp/modules/colour/colour.cl, srgb_encode8). Here each row's eight outputs per channel are float8
 * (row_apply8: the same sums per lane as row_apply, the column phase of each lane a mask), then
 * encoded where ENCODE_SRGB and stored as three consecutive vectors (store.h's store_rgb8).
 * Halo RADIUS. Launched over ceil(out_w / 8) x out_h / CFA_PERIOD work-items with a bounds check;
 * the last work-item of a row starts at out_w - 8 (it rewrites a few pixels with the same values),
 * so out_w >= 8. Needs NOUT 3, CFA_PERIOD 2 and out_h a multiple of it. */
#if CFA_PERIOD == 2 && NOUT == 3
__kernel void phase_filter_px8(__global const RAW_T *restrict src, __global out_t *restrict dst,
                               const int in_w, const int out_w, const int out_h,
                               __constant const float *restrict w, __constant const float *restrict bias)
{
    const int gx = (int)get_global_id(0) * 8;
    const int by = get_global_id(1) * CFA_PERIOD;
    if (gx >= out_w || by >= out_h) return;
    const int x = eight_from(gx, out_w);
    const int8 odd = (int8)(0, -1, 0, -1, 0, -1, 0, -1);
    const int8 m1 = ((x + PHASE_X) & 1) ? ~odd : odd;         /* the lanes of column phase 1 */
    #pragma unroll
    for (int i = 0; i < CFA_PERIOD; ++i) {
        const int y = by + i;
        float8 v[TAPS];
        float8 o[NOUT];
        #pragma unroll
        for (int dy = 0; dy < SIDE; ++dy) {                 /* each sample of the row read once */
            __global const RAW_T *a = src + (y + dy) * in_w + x;
            float f[8 + 2 * RADIUS];
            #pragma unroll
            for (int k = 0; k < 8 + 2 * RADIUS; ++k)
                f[k] = (float)a[k];
            #pragma unroll
            for (int dx = 0; dx < SIDE; ++dx)
                v[dy * SIDE + dx] = (float8)(f[dx], f[dx + 1], f[dx + 2], f[dx + 3],
                                             f[dx + 4], f[dx + 5], f[dx + 6], f[dx + 7]);
        }
        row_apply8((i + PHASE_Y) % CFA_PERIOD, m1, v, o, w, bias);
        store_rgb8(dst + 3 * (y * out_w + x), o[0], o[1], o[2]);
    }
}
#endif

/* phase_filter_p4x8: the period-4 filter for eight neighbouring columns per work-item, writing H x W x 3
 * (the host's layout) with the tone curve in its store, for CPU devices: the block kernel strides by
 * the period and PoCL does not vectorise it, and with the curve inside it ran at a seventh of its
 * speed (README.md). The eight columns start on a multiple of 4 (out_w is one), so columns j and
 * j + 4 share the CFA phase j (with PHASE_X): per row and phase the generated phase2_apply computes
 * the two as a float2, the phase a compile-time constant, every output once, then the eight are
 * gathered per channel and stored by store_rgb8. Halo RADIUS. Launched over ceil(out_w / 8) x
 * out_h / 4 work-items with a bounds check; the last of a row starts at out_w - 8. Needs NOUT 3,
 * CFA_PERIOD 4, out_w >= 8 and out_w, out_h multiples of 4. */
#if CFA_PERIOD == 4 && NOUT == 3
__kernel void phase_filter_p4x8(__global const RAW_T *restrict src, __global out_t *restrict dst,
                                const int in_w, const int out_w, const int out_h,
                                __constant const float *restrict w, __constant const float *restrict bias)
{
    const int gx = (int)get_global_id(0) * 8;
    const int by = get_global_id(1) * CFA_PERIOD;
    if (gx >= out_w || by >= out_h) return;
    const int x = eight_from(gx, out_w);
    #pragma unroll
    for (int i = 0; i < CFA_PERIOD; ++i) {
        const int y = by + i;
        float f[SIDE][8 + 2 * RADIUS];
        #pragma unroll
        for (int dy = 0; dy < SIDE; ++dy) {                 /* each sample of the rows read once */
            __global const RAW_T *a = src + (y + dy) * in_w + x;
            #pragma unroll
            for (int k = 0; k < 8 + 2 * RADIUS; ++k)
                f[dy][k] = (float)a[k];
        }
        float2 o[4][NOUT];
        #pragma unroll
        for (int j = 0; j < 4; ++j) {
            float2 v[TAPS];
            #pragma unroll
            for (int t = 0; t < TAPS; ++t)
                v[t] = (float2)(f[t / SIDE][j + t % SIDE], f[t / SIDE][j + 4 + t % SIDE]);
            phase2_apply(((i + PHASE_Y) % CFA_PERIOD) * CFA_PERIOD + (j + PHASE_X) % CFA_PERIOD, v, o[j], w, bias);
        }
        store_rgb8(dst + 3 * (y * out_w + x),
                   (float8)(o[0][0].s0, o[1][0].s0, o[2][0].s0, o[3][0].s0, o[0][0].s1, o[1][0].s1, o[2][0].s1, o[3][0].s1),
                   (float8)(o[0][1].s0, o[1][1].s0, o[2][1].s0, o[3][1].s0, o[0][1].s1, o[1][1].s1, o[2][1].s1, o[3][1].s1),
                   (float8)(o[0][2].s0, o[1][2].s0, o[2][2].s0, o[3][2].s0, o[0][2].s1, o[1][2].s1, o[2][2].s1, o[3][2].s1));
    }
}
#endif
