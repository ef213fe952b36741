/* ri_chroma_fit of the RI Bayer demosaic (demosaic_ri.cl has the other steps and the conventions;
 * reference.py, chroma_fit): a program of its own because it is compiled once per pixel class
 * (RI_OFF_Y, RI_OFF_X), and one small kernel compiles in a fraction of the whole file's time.
 *
 * Defines, all from the host (stage.py, chroma_fit_defines; none has a default here): RAW_T, RI_SCALE,
 * RI_RMSE_FLOOR, RI_MLRI_FLOOR, RI_CHROMA_R, RI_OFF_Y, RI_OFF_X. */

#if !defined(RAW_T) || !defined(RI_SCALE) || !defined(RI_RMSE_FLOOR) || !defined(RI_MLRI_FLOOR) \
    || !defined(RI_CHROMA_R) || !defined(RI_OFF_Y) || !defined(RI_OFF_X)
#error "demosaic_ri_chroma_fit.cl takes every define from the host (clisp/modules/demosaic_ri/stage.py)"
#endif

#include "guided.h"
#include "demosaic_ri.h"

/* ri_chroma_fit: the weighted MLRI fit of one colour from G over its sites in the CHROMA_N x
 * CHROMA_N window of every output pixel of one class: the pixels (2 gy + sy, 2 gx + sx), whose
 * offsets to the colour's lattice are the program's RI_OFF_Y, RI_OFF_X (0: the pixel is on the
 * colour's rows / columns), so that the window's sites are known when compiling: 9, 6 or 4 taps
 * instead of 25 masked ones. Written as (a w, b w, w) to planes base..base + 2 of the 6-plane image
 * (R: 0, B: 3): slope a = (sum(L g L x) / n) / max(sum (L g)^2 / n, RI_MLRI_FLOOR) over the n sites
 * (laps: L g, L x), plus reg_shot mean g + reg_floor (the host's CHROMA_NOISE_K 20 sigma^2 of G's noise at
 * the window's mean G, 8-bit units; 0 when noiseless), b = mean x - a mean g, the weight from that
 * fit's RMSE; moments centred on the
 * centre's G and on the colour's sample next to the centre. One colour per work-item (two are alike:
 * SLP); R's class (sy, sx) and B's (1 - sy, 1 - sx) have the same offsets, so one launch 2 deep
 * does both (get_group_id(2): which). Halo RI_CHROMA_R. */
__kernel void ri_chroma_fit(__global const RAW_T *restrict raw, const int raw_w, const int raw_m,
                            __global const float *restrict g, const int g_w, const int g_m,
                            __global const float *restrict laps, const int laps_w, const int laps_plane,
                            const int laps_m, __global float *restrict out, const int w, const int h,
                            const int sy0, const int sx0, const int base0, const float reg_shot,
                            const float reg_floor)
{
    /* the class (sy0, sx0) of colour base0 (work-groups 0 along the third index), and with a launch
     * 2 deep also the other colour's class of the same offsets, (1 - sy0, 1 - sx0) of 3 - base0 */
    const int other = (int)get_group_id(2);
    const int sy = other ? 1 - sy0 : sy0, sx = other ? 1 - sx0 : sx0, base = other ? 3 - base0 : base0;
    const int x = 2 * inward_id(0, (w - 1 - sx) / 2) + sx, y = 2 * inward_id(1, (h - 1 - sy) / 2) + sy;
    const int ra = (y + raw_m) * raw_w + x + raw_m;
    const float cx = RAW(raw, ra + RI_OFF_Y * raw_w + RI_OFF_X);     /* the colour's sample next to the centre */
    const float cg = g[(y + g_m) * g_w + x + g_m];
    gf_moments m = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    float ll = 0.0f, gg = 0.0f;
#pragma unroll
    for (int i = -RI_CHROMA_R; i <= RI_CHROMA_R; ++i)
#pragma unroll
        for (int j = -RI_CHROMA_R; j <= RI_CHROMA_R; ++j) {
            if (((i + RI_OFF_Y) & 1) == 0 && ((j + RI_OFF_X) & 1) == 0) {
                const float d = g[(y + g_m + i) * g_w + x + g_m + j] - cg;
                const float e = RAW(raw, ra + i * raw_w + j) - cx;
                const int la = (y + laps_m + i) * laps_w + x + laps_m + j;
                const float lg = laps[la], lx = laps[laps_plane + la];
                m.n += 1.0f;
                m.s1x += d;
                m.s1y += e;
                m.s2x += d * d;
                m.s2y += e * e;
                m.sxy += d * e;
                ll += lg * lx;
                gg += lg * lg;
            }
        }
    const float inv = 1.0f / m.n;
    float md, me, vg, vx, cv;
    gf_centred_stats(&m, inv, &md, &me, &vg, &vx, &cv);
    float aw, bw, wt;
    const float mg = cg + md;
    const float reg = reg_shot * (mg > 0.0f ? mg : 0.0f) + reg_floor;     /* K 20 sigma^2 at the mean G */
    ri_weighted_fit((ll * inv) / ((gg * inv > RI_MLRI_FLOOR ? gg * inv : RI_MLRI_FLOOR) + reg), mg, cx + me, vg, vx,
                    cv, &aw, &bw, &wt);
    const int o = y * w + x, p = w * h;
    out[base * p + o] = aw;
    out[(base + 1) * p + o] = bw;
    out[(base + 2) * p + o] = wt;
}
