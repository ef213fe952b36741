/* RI Bayer demosaic (one-pass adaptive residual interpolation) on the device. NumPy float64
 * reference and step list: reference.py beside this file (one kernel ri_<step> per step, same
 * names); host side: stage.py; schedule and measurements: README.md.
 *
 * Conventions (the project's tiling contract: valid-only windows, no borders, no bounds checks):
 *  - Every kernel writes exactly w x h outputs (planar: plane p at p w h), launched inward (one
 *    launch over whole work-groups, the last shifted to end at the edge: common.h) and reads each input
 *    v through its pitch v_w (elements per row), its plane size v_plane where it has several
 *    planes, and its margin v_m: output pixel (y, x) lies at (y + v_m, x + v_m) of v.
 *  - The mosaic is read as RAW_T and multiplied by RI_SCALE (255) on load, so that the reference's
 *    constants (8-bit units) apply unchanged; ri_complete_rgb divides by it.
 *  - CFA sites from the parities (ry, rx) of the output grid: pixel (y, x) is R when y + ry and
 *    x + rx are even, B when both are odd, G otherwise.
 *  - No branch on per-pixel data: where the work depends on the site, both candidates are computed
 *    and one is selected, so that PoCL vectorises across work-items along x.
 *
 * Defines, all from the host (stage.py, program_defines; none has a default here): RAW_T, RI_SCALE,
 * RI_EPS, RI_RMSE_FLOOR, RI_WEIGHT_REG (ARI's constants), RI_MERGE_REG, RI_LINE_R
 * (the G fits' window radius along the line), RI_CHROMA_R (the chroma fits' window radius),
 * RI_SMOOTH (the merge's one-sided Gaussian taps, offsets 0..4), INTERLEAVED. ri_chroma_fit is a
 * program of its own (demosaic_ri_chroma_fit.cl): it is compiled once per pixel class. */

#if !defined(RAW_T) || !defined(RI_SCALE) || !defined(RI_EPS) || !defined(RI_RMSE_FLOOR) \
    || !defined(RI_WEIGHT_REG) || !defined(RI_MERGE_REG) || !defined(RI_LINE_R) || !defined(RI_CHROMA_R) \
    || !defined(RI_SMOOTH) || !defined(INTERLEAVED)
#error "demosaic_ri.cl takes every define from the host (clisp/modules/demosaic_ri/stage.py)"
#endif

#include "guided.h"
#include "demosaic_ri.h"

__constant float ri_smooth[5] = RI_SMOOTH;

__attribute__((always_inline)) inline int ri_is_green(const int y, const int x, const int ry, const int rx)
{
    return ((y + ry + x + rx) & 1) != 0;
}

#define LINE_N (2 * RI_LINE_R + 1)

/* The fits and tentatives of the four line directions (RI_FITS: along_x 1 then 0, swap 0 then 1 for
 * each) and the residuals of the two (along_x 1, 0) are one launch each, the direction k the
 * work-group's third index (work-groups 1 deep along it, so k is uniform over a group). */
#define RI_ALONG_X(k) (1 - ((k) >> 1))
#define RI_SWAP(k) ((k) & 1)

/* ri_green_fit: one weighted guided-filter fit of every window of LINE_N pixels along a line: the
 * G line g0 (G samples; the mean of the two neighbours along the line elsewhere) and the chroma line
 * c0 (the converse); direction k = get_group_id(2) in 0..3: along_x (RI_ALONG_X): along rows (1) or
 * columns (0); swap (RI_SWAP) 0: G from the chroma line, 1: the chroma line from G. Writes (a w, b w,
 * w) to planes 3 k..3 k + 2 of the 12-plane image. One fit per work-item: two in one body are
 * alike, LLVM's SLP vectoriser packs them, and PoCL then does not vectorise across work-items
 * (README.md). Halo 1 + RI_LINE_R along the line. */
__kernel void ri_green_fit(__global const RAW_T *restrict raw, const int raw_w, const int raw_m,
                           __global float *restrict out, const int w, const int h, const int ry, const int rx)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int k_dir = (int)get_group_id(2), along_x = RI_ALONG_X(k_dir), swap = RI_SWAP(k_dir), base = 3 * k_dir;
    const int c = (y + raw_m) * raw_w + x + raw_m, s = along_x ? 1 : raw_w;
    /* G parity of the window's first pixel; it alternates along the line */
    const int green0 = along_x ? ri_is_green(y, x - RI_LINE_R, ry, rx) : ri_is_green(y - RI_LINE_R, x, ry, rx);
    /* moments centred on the centre pixel's values (guided.h), in one pass */
    const float vc = RAW(raw, c), mc = 0.5f * (RAW(raw, c - s) + RAW(raw, c + s));
    const int gc = (green0 + RI_LINE_R) & 1;
    const float g0c = gc ? vc : mc, c0c = gc ? mc : vc;
    const float cxv = swap ? g0c : c0c, cyv = swap ? c0c : g0c;
    gf_moments mo = {(float)LINE_N, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
#pragma unroll
    for (int k = 0; k < LINE_N; ++k) {
        const int at = c + (k - RI_LINE_R) * s;
        const float v = RAW(raw, at), m = 0.5f * (RAW(raw, at - s) + RAW(raw, at + s));
        const int g = (green0 + k) & 1;
        const float g0 = g ? v : m, c0 = g ? m : v;
        const float d = (swap ? g0 : c0) - cxv, e = (swap ? c0 : g0) - cyv;
        mo.s1x += d;
        mo.s1y += e;
        mo.s2x += d * d;
        mo.s2y += e * e;
        mo.sxy += d * e;
    }
    float md, me, vx, vy, cv;
    gf_centred_stats(&mo, 1.0f / LINE_N, &md, &me, &vx, &vy, &cv);
    float aw, bw, wt;
    ri_weighted_fit(cv / (vx + RI_EPS), cxv + md, cyv + me, vx, vy, cv, &aw, &bw, &wt);
    const int i = y * w + x, p = w * h;
    out[base * p + i] = aw;
    out[(base + 1) * p + i] = bw;
    out[(base + 2) * p + i] = wt;
}

/* ri_green_apply: one tentative along a line per direction k = get_group_id(2) in 0..3 (as
 * ri_green_fit's), A q + B with A, B the 1 / RMSE-weighted means of the fit's coefficients (planes
 * 3 k..3 k + 2 of fits) over the LINE_N pixels along the line, q its guide at the pixel: the chroma
 * line c0 (swap 0: t_g) or the G line g0 (swap 1: t_c). Writes plane k of the 4-plane image. Halo
 * RI_LINE_R (the guide reads 1 more of the mosaic). */
__kernel void ri_green_apply(__global const RAW_T *restrict raw, const int raw_w, const int raw_m,
                             __global const float *restrict fits, const int fits_w, const int fits_plane,
                             const int fits_m, __global float *restrict out, const int w, const int h,
                             const int ry, const int rx)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int k_dir = (int)get_group_id(2), along_x = RI_ALONG_X(k_dir), swap = RI_SWAP(k_dir);
    const int base = 3 * k_dir, out_plane = k_dir;
    const int f = (y + fits_m) * fits_w + x + fits_m, sf = along_x ? 1 : fits_w;
    __global const float *aw = fits + base * fits_plane, *bw = aw + fits_plane, *ww = bw + fits_plane;
    float sa = 0.0f, sb = 0.0f, sw = 0.0f;
#pragma unroll
    for (int k = -RI_LINE_R; k <= RI_LINE_R; ++k) {
        sa += aw[f + k * sf];
        sb += bw[f + k * sf];
        sw += ww[f + k * sf];
    }
    const int c = (y + raw_m) * raw_w + x + raw_m, s = along_x ? 1 : raw_w;
    const float v = RAW(raw, c), m = 0.5f * (RAW(raw, c - s) + RAW(raw, c + s));
    const int g = ri_is_green(y, x, ry, rx);
    const float guide = (g != swap) ? m : v;     /* c0 (swap 0) or g0 (swap 1) at the pixel */
    out[out_plane * w * h + y * w + x] = (sa * guide + sb) / (sw + RI_WEIGHT_REG);
}

/* ri_green_residual: the colour difference G - C along one line direction j = get_group_id(2)
 * (along_x 1 - j: rows, then columns; tent: planes t_g, t_c of it from plane 2 j) written to plane
 * j: at a G site raw - (t_c + the mean residual raw - t_c of the two neighbours along the line), at
 * a chroma site t_g + the mean residual raw - t_g of the two neighbours - raw. Halo 1. */
__kernel void ri_green_residual(__global const RAW_T *restrict raw, const int raw_w, const int raw_m,
                                __global const float *restrict tent, const int tent_w, const int tent_plane,
                                const int tent_m, __global float *restrict out, const int w, const int h,
                                const int ry, const int rx)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int j_dir = (int)get_group_id(2), along_x = 1 - j_dir, base = 2 * j_dir, out_plane = j_dir;
    const int c = (y + raw_m) * raw_w + x + raw_m, s = along_x ? 1 : raw_w;
    const int t = base * tent_plane + (y + tent_m) * tent_w + x + tent_m, st = along_x ? 1 : tent_w;
    const int g = ri_is_green(y, x, ry, rx);
    const int own = g ? tent_plane : 0;          /* the missing channel's tentative: t_c at G, t_g at C */
    const float centre = RAW(raw, c);
    const float est = tent[t + own] + 0.5f * (RAW(raw, c - s) - tent[t + own - st] + RAW(raw, c + s) - tent[t + own + st]);
    out[out_plane * w * h + y * w + x] = g ? centre - est : est - centre;
}

/* Sum over the 3 x 3 pixels around index a of |d(+s) - d(-s)| (the colour-difference gradient
 * along the step s; rows of pitch dw). */
__attribute__((always_inline)) inline float ri_gradient_sum(__global const float *restrict d, const int a,
                                                            const int s, const int dw)
{
    float sum = 0.0f;
#pragma unroll
    for (int i = -1; i <= 1; ++i)
#pragma unroll
        for (int j = -1; j <= 1; ++j) {
            const int at = a + i * dw + j;
            sum += __builtin_fabsf(d[at + s] - d[at - s]);
        }
    return sum;
}

/* ri_green_merge: G everywhere, the GBTF merge of the two colour differences (dif: planes h, v) at
 * chroma sites: weights 1 / (D^2 + RI_MERGE_REG), D the gradient sums one pixel W, E (rows) and N,
 * S (columns); each side's difference smoothed by RI_SMOOTH towards it. Halo 4 (the smoothing;
 * the gradient sums read 3). */
__kernel void ri_green_merge(__global const RAW_T *restrict raw, const int raw_w, const int raw_m,
                             __global const float *restrict dif, const int dif_w, const int dif_plane,
                             const int dif_m, __global float *restrict out, const int w, const int h,
                             const int ry, const int rx)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int a = (y + dif_m) * dif_w + x + dif_m;
    __global const float *dh = dif, *dv = dif + dif_plane;
    const float d_w = ri_gradient_sum(dh, a - 1, 1, dif_w), d_e = ri_gradient_sum(dh, a + 1, 1, dif_w);
    const float d_n = ri_gradient_sum(dv, a - dif_w, dif_w, dif_w), d_s = ri_gradient_sum(dv, a + dif_w, dif_w, dif_w);
    const float w_w = 1.0f / (d_w * d_w + RI_MERGE_REG), w_e = 1.0f / (d_e * d_e + RI_MERGE_REG);
    const float w_n = 1.0f / (d_n * d_n + RI_MERGE_REG), w_s = 1.0f / (d_s * d_s + RI_MERGE_REG);
    float s_w = 0.0f, s_e = 0.0f, s_n = 0.0f, s_s = 0.0f;
#pragma unroll
    for (int k = 0; k < 5; ++k) {
        s_w += ri_smooth[k] * dh[a - k];
        s_e += ri_smooth[k] * dh[a + k];
        s_n += ri_smooth[k] * dv[a - k * dif_w];
        s_s += ri_smooth[k] * dv[a + k * dif_w];
    }
    const float merged = (w_w * s_w + w_e * s_e + w_n * s_n + w_s * s_s) / (w_w + w_e + w_n + w_s);
    const float centre = RAW(raw, (y + raw_m) * raw_w + x + raw_m);
    out[y * w + x] = ri_is_green(y, x, ry, rx) ? centre : centre + merged;
}

#define CHROMA_N (2 * RI_CHROMA_R + 1)

/* ri_chroma_laplacians: the Laplacians of G and of the mosaic (2 planes; L: 4 at the centre, -1
 * two pixels away along each axis; on the R (B) sites the mosaic's is that of the R (B) samples).
 * Halo 2. */
__kernel void ri_chroma_laplacians(__global const RAW_T *restrict raw, const int raw_w, const int raw_m,
                                   __global const float *restrict g, const int g_w, const int g_m,
                                   __global float *restrict out, const int w, const int h, const int ry,
                                   const int rx)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int ga = (y + g_m) * g_w + x + g_m, ra = (y + raw_m) * raw_w + x + raw_m;
    out[y * w + x] = 4.0f * g[ga] - g[ga - 2] - g[ga + 2] - g[ga - 2 * g_w] - g[ga + 2 * g_w];
    out[w * h + y * w + x] = 4.0f * RAW(raw, ra) - RAW(raw, ra - 2) - RAW(raw, ra + 2) - RAW(raw, ra - 2 * raw_w)
                             - RAW(raw, ra + 2 * raw_w);
}

/* ri_chroma_apply: the tentative R and B (2 planes), A g + B with A, B the 1 / RMSE-weighted means
 * of the fits (6 planes) over the CHROMA_N x CHROMA_N window. Halo RI_CHROMA_R. */
__kernel void ri_chroma_apply(__global const float *restrict fits, const int fits_w, const int fits_plane,
                              const int fits_m, __global const float *restrict g, const int g_w, const int g_m,
                              __global float *restrict out, const int w, const int h)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    /* scalar sums (an array indexed in the unrolled loop took PoCL 10 s to compile) */
    float ar = 0.0f, br = 0.0f, wr = 0.0f, ab = 0.0f, bb = 0.0f, wb = 0.0f;
    __global const float *f = fits + (y + fits_m) * fits_w + x + fits_m;
#pragma unroll
    for (int i = -RI_CHROMA_R; i <= RI_CHROMA_R; ++i)
#pragma unroll
        for (int j = -RI_CHROMA_R; j <= RI_CHROMA_R; ++j) {
            const int at = i * fits_w + j;
            ar += f[at];
            br += f[fits_plane + at];
            wr += f[2 * fits_plane + at];
            ab += f[3 * fits_plane + at];
            bb += f[4 * fits_plane + at];
            wb += f[5 * fits_plane + at];
        }
    const float gv = g[(y + g_m) * g_w + x + g_m];
    out[y * w + x] = (ar * gv + br) / (wr + RI_WEIGHT_REG);
    out[w * h + y * w + x] = (ab * gv + bb) / (wb + RI_WEIGHT_REG);
}

/* ri_complete_rgb: R, G, B (3 planes, or H x W x 3 with INTERLEAVED) times the 3 x 3 matrix m
 * (identity unless a colour matrix was fused in), back in the mosaic's units: at the R (B) sites the
 * sample, elsewhere the tentative plus the bilinear interpolation of the residual (sample -
 * tentative) at the neighbouring R (B) sites. Halo 1. */
__kernel void ri_complete_rgb(__global const RAW_T *restrict raw, const int raw_w, const int raw_m,
                              __global const float *restrict tent, const int tent_w, const int tent_plane,
                              const int tent_m, __global const float *restrict g, const int g_w, const int g_m,
                              __global float *restrict out, const int w, const int h, const int ry,
                              const int rx, __constant float *m)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int t = (y + tent_m) * tent_w + x + tent_m, r = (y + raw_m) * raw_w + x + raw_m;
    float res_r = 0.0f, res_b = 0.0f;
#pragma unroll
    for (int i = -1; i <= 1; ++i)
#pragma unroll
        for (int j = -1; j <= 1; ++j) {
            const float k = (i == 0 ? 1.0f : 0.5f) * (j == 0 ? 1.0f : 0.5f);
            const int row_r = ((y + i + ry) & 1) == 0, col_r = ((x + j + rx) & 1) == 0;
            const float mr = (row_r & col_r) ? k : 0.0f, mb = (!row_r & !col_r) ? k : 0.0f;
            const float v = RAW(raw, r + i * raw_w + j);
            res_r += mr * (v - tent[t + i * tent_w + j]);
            res_b += mb * (v - tent[tent_plane + t + i * tent_w + j]);
        }
    const float red = (tent[t] + res_r) * (1.0f / RI_SCALE);
    const float green = g[(y + g_m) * g_w + x + g_m] * (1.0f / RI_SCALE);
    const float blue = (tent[tent_plane + t] + res_b) * (1.0f / RI_SCALE);
    const float o0 = m[0] * red + m[1] * green + m[2] * blue;
    const float o1 = m[3] * red + m[4] * green + m[5] * blue;
    const float o2 = m[6] * red + m[7] * green + m[8] * blue;
#if INTERLEAVED
    const int o = 3 * (y * w + x);
    out[o] = o0;
    out[o + 1] = o1;
    out[o + 2] = o2;
#else
    const int o = y * w + x;
    out[o] = o0;
    out[w * h + o] = o1;
    out[2 * w * h + o] = o2;
#endif
}
