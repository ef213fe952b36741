/* ARI Bayer demosaic (adaptive residual interpolation, Monno et al. 2015/2017) on the device. NumPy
 * float64 reference: reference.py beside this file (demosaic_ari, _ari_green, _merge_green,
 * _ari_chroma, guided_pair, guided_filter, _criterion, _adaptive); host side: stage.py; schedule,
 * halo and why the kernels are shaped so (PoCL's vectoriser, and how to check it): README.md.
 *
 * Conventions (the project's tiling contract: valid-only windows, no borders, no bounds checks):
 *  - Data are in 8-bit units (the host scales the mosaic by 255 once, ari_scale), so the reference's
 *    constants apply unchanged (the defines ARI_EPS, ARI_RMSE_FLOOR, ARI_WEIGHT_REG, ARI_CRIT_REG).
 *  - Every kernel writes an image of exactly w x h (planar: plane p at p w h; parameters out, w, h),
 *    launched in one command (its coordinates from common.h's inward_id), and reads its inputs through "views": an input v is the parameters v (the buffer),
 *    v_base (the element of v that lies at output pixel (0, 0)), v_pitch (elements per row) and, for
 *    several planes, v_plane (elements per plane), so input pixel (y + dy, x + dx) of plane p is
 *    v[v_base + p v_plane + (y + dy) v_pitch + x + dx]. The host launches every kernel by these names,
 *    tracks each image's margin (its offset inside the stage's input window) and checks every read
 *    stays inside its input; a kernel's "halo" below is how far it reads around the output pixel.
 *  - CFA sites from the parities (py, px) of the output grid: R rows are those with y + py even, R
 *    columns x + px even; R = R row & R column, B = neither, G = one of them (x + y + px + py odd).
 *  - Directions are steps (sy, sx): h (0, 1), v (1, 0), d1 (1, 1), d2 (1, -1).
 *
 * Defines, all from the host and every one in every program (stage.py's program_defines; none has
 * a default here): ARI_EPS, ARI_RMSE_FLOOR, ARI_WEIGHT_REG, ARI_CRIT_REG, ARI_CRIT_FLOOR
 * (reference.py's ARI_EPS, ARI_RMSE_FLOOR, WEIGHT_REG, CRIT_REG, CRIT_FLOOR); the site codes SITE_R,
 * SITE_B, SITE_C (R or B), SITE_G; and the
 * modes of the launched kernel (0 where it does not read them): ARI_DIR (0: lines are rows, windows
 * along x; 1: columns, along y), ARI_MLRI (slope from the Laplacian moments), ARI_PAIR (step 1: the
 * fits of a line pair, statistics per line set ARI_SET, fit ARI_FIT), ARI_SY, ARI_SX (the criterion's
 * direction), ARI_REGION (step 2's criterion over the chroma sites), ARI_KNOWN, ARI_TARGET (the chroma
 * kernels' sites), ARI_R (the window radius of the box kernels), ARI_P, ARI_Q, ARI_LS, ARI_KNOWN (the
 * diagonal kernels' lattice radii, direction and Laplacian sites). Radii and modes are compile-time so
 * that every kernel body is straight-line code, which PoCL vectorises across work-items (README.md).
 * ARI_WITH_<kernel>: the kernels a program holds (those that read the same modes as the launched
 * one), so that a program compiles only what can run with its modes. */

#if !defined(ARI_EPS) || !defined(ARI_RMSE_FLOOR) || !defined(ARI_WEIGHT_REG) || !defined(ARI_CRIT_REG) \
    || !defined(ARI_CRIT_FLOOR) || !defined(SITE_R) || !defined(SITE_B) || !defined(SITE_C) || !defined(SITE_G) \
    || !defined(ARI_DIR) \
    || !defined(ARI_MLRI) || !defined(ARI_PAIR) || !defined(ARI_R) || !defined(ARI_SET) || !defined(ARI_FIT) \
    || !defined(ARI_SY) || !defined(ARI_SX) || !defined(ARI_REGION) || !defined(ARI_KNOWN) || !defined(ARI_TARGET) \
    || !defined(ARI_P) || !defined(ARI_Q) || !defined(ARI_LS)
#error "demosaic_ari.cl takes every define from the host (clisp/modules/demosaic_ari/stage.py, program_defines)"
#endif

#include "guided.h"

/* 1.0f where pixel (y, x) of a grid with parities (py, px) is a site of kind ``code``, else 0.0f. */
__attribute__((always_inline)) inline float ari_site(const int code, const int y, const int x, const int py, const int px)
{
    const int ry = ((y + py) & 1) == 0, rx = ((x + px) & 1) == 0;
    const int r = code == SITE_R ? (ry & rx) : code == SITE_B ? (!ry & !rx)
                : code == SITE_C ? (ry == rx) : (ry != rx);
    return r ? 1.0f : 0.0f;
}

__attribute__((always_inline)) inline int ari_is_green(const int y, const int x, const int py, const int px)
{
    return ((y + py + x + px) & 1) != 0;
}

/* Weighted fit y ~ a x + b from centred window statistics (ARI's guided filter, weighted form):
 * mse = a^2 var_x - 2 a cov + var_y, w = 1 / max(sqrt(max(mse, 0)), floor); r[0..2] = a w, b w, w. */
__attribute__((always_inline)) inline void ari_fit_values(const float a, const float mean_x, const float mean_y, const float var_x,
                           const float var_y, const float cov, float *r)
{
    const float b = mean_y - a * mean_x;
    const float mse = a * a * var_x - 2.0f * a * cov + var_y;
    const float rmse = __builtin_sqrtf(mse > 0.0f ? mse : 0.0f);
    const float wt = 1.0f / (rmse > ARI_RMSE_FLOOR ? rmse : ARI_RMSE_FLOOR);
    r[0] = a * wt;
    r[1] = b * wt;
    r[2] = wt;
}

/* ari_scale: out = src * scale (the mosaic in 8-bit units). Halo 0. */
#ifdef ARI_WITH_ari_scale
__kernel void ari_scale(__global const float *restrict src, const int src_base, const int src_pitch,
                        __global float *restrict out, const int w, const int h, const float scale)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    out[y * w + x] = src[src_base + y * src_pitch + x] * scale;
}
#endif

/* ari_green_start: the lines of ARI step 1 before the iterations, along d = (sy, sx): m = mean of the
 * two neighbours along d; planes g0 = G sites ? raw : m, c0 = G sites ? m : raw. Halo 1 along d. */
#ifdef ARI_WITH_ari_green_start
__kernel void ari_green_start(__global const float *restrict raw, const int raw_base, const int raw_pitch,
                              __global float *restrict out, const int w, const int h, const int sy, const int sx,
                              const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int at = raw_base + y * raw_pitch + x, s = sy * raw_pitch + sx;
    const float v = raw[at], m = 0.5f * raw[at - s] + 0.5f * raw[at + s];
    const int g = ari_is_green(y, x, py, px);
    out[y * w + x] = g ? v : m;
    out[w * h + y * w + x] = g ? m : v;
}
#endif

/* ari_along_moments: first (separable) pass of the window statistics of guide x and target y, along
 * the lines (ARI_DIR 0: x axis, 1: y axis), radius r = ARI_R: for output (y, x) the sums over k = -r..r of
 * 1, d, e, d^2, e^2, d e with d = x(k) - x(0), e = y(k) - y(0) (centred on the output pixel; the
 * across pass moves them to the window's centre). ARI_MLRI adds the Laplacian moments over a site set
 * (L = [-1, 0, 2, 0, -1] along the line): ARI_PAIR (step 1; x = chroma line c, y = G line g): over G
 * sites sum L(x) L(y), sum L(x)^2, count, then over chroma sites sum L(x) L(y), sum L(y)^2, count
 * (12 planes); else (step 3) over chroma sites sum L(x) L(y), sum L(x)^2, count (9 planes); plain: 6
 * planes. Halo r along the line (r + 2 with ARI_MLRI). */
#ifdef ARI_WITH_ari_along_moments
__kernel void ari_along_moments(__global const float *restrict xs, const int xs_base, const int xs_pitch,
                                __global const float *restrict ys, const int ys_base, const int ys_pitch,
                                __global float *restrict out, const int w, const int h, const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
#if ARI_DIR == 0
    const int xs_step = 1, ys_step = 1;
#else
    const int xs_step = xs_pitch, ys_step = ys_pitch;
#endif
    __global const float *xc = xs + xs_base + y * xs_pitch + x;
    __global const float *yc = ys + ys_base + y * ys_pitch + x;
    const float cx = xc[0], cy = yc[0];
    float n = 0.0f, sd = 0.0f, se = 0.0f, sdd = 0.0f, see = 0.0f, sde = 0.0f;
#if ARI_MLRI
    float g_xy = 0.0f, g_xx = 0.0f, g_n = 0.0f, c_xy = 0.0f, c_yy = 0.0f, c_xx = 0.0f, c_n = 0.0f;
#endif
#pragma unroll
    for (int k = -ARI_R; k <= ARI_R; ++k) {
        const float xv = xc[k * xs_step], yv = yc[k * ys_step];
        const float d = xv - cx, e = yv - cy;
        n += 1.0f;
        sd += d;
        se += e;
        sdd += d * d;
        see += e * e;
        sde += d * e;
#if ARI_MLRI
        const float lx = 2.0f * xv - xc[(k - 2) * xs_step] - xc[(k + 2) * xs_step];
        const float ly = 2.0f * yv - yc[(k - 2) * ys_step] - yc[(k + 2) * ys_step];
#if ARI_DIR == 0
        const int green = ari_is_green(y, x + k, py, px);
#else
        const int green = ari_is_green(y + k, x, py, px);
#endif
        const float gm = green ? 1.0f : 0.0f, cm = 1.0f - gm;
        c_xy += cm * lx * ly;
        c_n += cm;
#if ARI_PAIR
        g_xy += gm * lx * ly;
        g_xx += gm * lx * lx;
        g_n += gm;
        c_yy += cm * ly * ly;
#else
        c_xx += cm * lx * lx;
#endif
#endif
    }
    const int i = y * w + x, plane = w * h;
    out[i] = n;
    out[plane + i] = sd;
    out[2 * plane + i] = se;
    out[3 * plane + i] = sdd;
    out[4 * plane + i] = see;
    out[5 * plane + i] = sde;
#if ARI_MLRI && ARI_PAIR
    out[6 * plane + i] = g_xy;
    out[7 * plane + i] = g_xx;
    out[8 * plane + i] = g_n;
    out[9 * plane + i] = c_xy;
    out[10 * plane + i] = c_yy;
    out[11 * plane + i] = c_n;
#elif ARI_MLRI
    out[6 * plane + i] = c_xy;
    out[7 * plane + i] = c_xx;
    out[8 * plane + i] = c_n;
#endif
}
#endif

/* Accumulator of centred window moments: gf_moments of clisp/modules/common/guided.h. */
typedef gf_moments ari_moments;

/* Add the along-pass moments of one line (planes at index i, stride rp), centred on (cxj, cyj), to m,
 * moved to the centre (cx, cy): dx = cxj - cx, dy = cyj - cy (gf_add_moved). */
__attribute__((always_inline)) inline void ari_add_line(ari_moments *m, __global const float *restrict rows, const int i, const int rp,
                         const float dx, const float dy)
{
    gf_add_moved(m, rows[i], rows[rp + i], rows[2 * rp + i], rows[3 * rp + i], rows[4 * rp + i], rows[5 * rp + i],
                 dx, dy);
}

/* Means, variances and covariance of accumulated moments centred on (cx, cy), given inv = 1 / max(N, 1)
 * (gf_centred_stats; the means as cx N / n + E[d], so that an empty window's are 0, as the reference's). */
__attribute__((always_inline)) inline void ari_stats_inv(const ari_moments *m, const float inv, const float cx, const float cy,
                          float *mean_x, float *mean_y, float *var_x, float *var_y, float *cov)
{
    float md, me;
    gf_centred_stats(m, inv, &md, &me, var_x, var_y, cov);
    *mean_x = cx * (m->n * inv) + md;
    *mean_y = cy * (m->n * inv) + me;
}

/* Means, variances and covariance (over n = max(N, 1)) of accumulated moments centred on (cx, cy). */
__attribute__((always_inline)) inline void ari_stats(const ari_moments *m, const float cx, const float cy, float *mean_x, float *mean_y,
                      float *var_x, float *var_y, float *cov)
{
    ari_stats_inv(m, 1.0f / (m->n > 1.0f ? m->n : 1.0f), cx, cy, mean_x, mean_y, var_x, var_y, cov);
}

/* MLRI slope: (s_xy / n) / (s_xx / n + eps), n = max(count, 1) (the floor of the mean squared
 * Laplacian is 0 in ARI). */
__attribute__((always_inline)) inline float ari_lap_slope(const float s_xy, const float s_xx, const float count)
{
    const float inv = 1.0f / (count > 1.0f ? count : 1.0f);
    return (s_xy * inv) / (s_xx * inv + ARI_EPS);
}

/* ari_across_coefficients: second pass of the window statistics, across the lines, radius r = ARI_R, then
 * the weighted fits. rows: the planes of ari_along_moments (row pitch rows_pitch, plane stride
 * rows_plane; rows[(y + r + j) rows_pitch + x] is the line at output row y + j for ARI_DIR 0,
 * rows[y rows_pitch + x + r + j] the column x + j for 1), each centred on the x, y values of its own
 * output pixel, read from the views xs, ys (aligned to the output). Output planes from element
 * out_base of out. ARI_PAIR (step 1):
 * the lines of line set ARI_SET (0: R lines, 1: B lines: rows / columns of that parity): the lines
 * at even and at odd offsets j are summed apart (no branch: j is compile-time), then each pixel takes
 * the sums of its set's parity; ARI_FIT 0: the fit of y (G line) from x (chroma line), planes a_g w,
 * b_g w, w_g; 1: of x from y, a_c w, b_c w, w_c (one fit per program: two alike fits in one body are
 * SLP-packed into <2 x float> operations, which keeps PoCL from vectorising across work-items; the
 * host launches the 4 (set, fit) programs into planes 0-2, 3-5, 6-8, 9-11). Else (step 3): every
 * line, the fit of y from x, 3 planes. Halo r across the lines. */
#ifdef ARI_WITH_ari_across_coefficients
__kernel void ari_across_coefficients(__global const float *restrict rows, const int rows_pitch, const int rows_plane,
                                      __global const float *restrict xs, const int xs_base, const int xs_pitch,
                                      __global const float *restrict ys, const int ys_base, const int ys_pitch,
                                      __global float *restrict out, const int out_base, const int w, const int h,
                                      const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const float cx = xs[xs_base + y * xs_pitch + x], cy = ys[ys_base + y * ys_pitch + x];
#if ARI_DIR == 0
    const int line_step = rows_pitch, xstep = xs_pitch, ystep = ys_pitch;
    const int at0 = (y + ARI_R) * rows_pitch + x;
#else
    const int line_step = 1, xstep = 1, ystep = 1;
    const int at0 = y * rows_pitch + x + ARI_R;
#endif
    const int xa = xs_base + y * xs_pitch + x, ya = ys_base + y * ys_pitch + x;
#if ARI_PAIR
#if ARI_DIR == 0
    const int line0 = y + py;
#else
    const int line0 = x + px;
#endif
    /* the lines j = -r, -r + 2, ... (a) and j = -r + 1, ... (b), then those of set ARI_SET */
    ari_moments ma = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f}, mb = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    float la[3] = {0.0f, 0.0f, 0.0f}, lb[3] = {0.0f, 0.0f, 0.0f};
#pragma unroll
    for (int j = -ARI_R; j <= ARI_R; ++j) {
        const int i = at0 + j * line_step;
        const int in_a = ((j + ARI_R) & 1) == 0;
        const float dx = xs[xa + j * xstep] - cx, dy = ys[ya + j * ystep] - cy;
        if (in_a)
            ari_add_line(&ma, rows, i, rows_plane, dx, dy);
        else
            ari_add_line(&mb, rows, i, rows_plane, dx, dy);
#if ARI_MLRI
#pragma unroll
        for (int t = 0; t < 3; ++t) {
            if (in_a)
                la[t] += rows[(6 + 3 * ARI_FIT + t) * rows_plane + i];
            else
                lb[t] += rows[(6 + 3 * ARI_FIT + t) * rows_plane + i];
        }
#endif
    }
    const int use_a = ((line0 + ARI_R) & 1) == ARI_SET;
    ari_moments m;
    m.n = use_a ? ma.n : mb.n;
    m.s1x = use_a ? ma.s1x : mb.s1x;
    m.s1y = use_a ? ma.s1y : mb.s1y;
    m.s2x = use_a ? ma.s2x : mb.s2x;
    m.s2y = use_a ? ma.s2y : mb.s2y;
    m.sxy = use_a ? ma.sxy : mb.sxy;
    float l[3];
#pragma unroll
    for (int t = 0; t < 3; ++t)
        l[t] = use_a ? la[t] : lb[t];
    float mean_x, mean_y, var_x, var_y, cov;
    ari_stats(&m, cx, cy, &mean_x, &mean_y, &var_x, &var_y, &cov);
    float f[3];
#if ARI_MLRI
    const float a = ari_lap_slope(l[0], l[1], l[2]);
#elif ARI_FIT == 0
    const float a = cov / (var_x + ARI_EPS);
#else
    const float a = cov / (var_y + ARI_EPS);
#endif
#if ARI_FIT == 0
    ari_fit_values(a, mean_x, mean_y, var_x, var_y, cov, f);
#else
    ari_fit_values(a, mean_y, mean_x, var_y, var_x, cov, f);
#endif
    const int i = y * w + x, plane = w * h;
#pragma unroll
    for (int t = 0; t < 3; ++t)
        out[out_base + t * plane + i] = f[t];
#else
    ari_moments m = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    float l[3] = {0.0f, 0.0f, 0.0f};
#pragma unroll
    for (int j = -ARI_R; j <= ARI_R; ++j) {
        const int i = at0 + j * line_step;
        ari_add_line(&m, rows, i, rows_plane, xs[xa + j * xstep] - cx, ys[ya + j * ystep] - cy);
#if ARI_MLRI
#pragma unroll
        for (int t = 0; t < 3; ++t)
            l[t] += rows[(6 + t) * rows_plane + i];
#endif
    }
    float mean_x, mean_y, var_x, var_y, cov;
#if ARI_MLRI
    /* one division for 1 / max(n, 1) and the slope, as in ari_diag_coefficients (two are SLP-packed) */
    const float nn = m.n > 1.0f ? m.n : 1.0f, ln = l[2] > 1.0f ? l[2] : 1.0f;
    const float den = l[1] + ARI_EPS * ln, r = 1.0f / (nn * den);
    ari_stats_inv(&m, den * r, cx, cy, &mean_x, &mean_y, &var_x, &var_y, &cov);
    const float a = l[0] * nn * r;
#else
    ari_stats(&m, cx, cy, &mean_x, &mean_y, &var_x, &var_y, &cov);
    const float a = cov / (var_x + ARI_EPS);
#endif
    float f[3];
    ari_fit_values(a, mean_x, mean_y, var_x, var_y, cov, f);
    const int i = y * w + x, plane = w * h;
    out[out_base + i] = f[0];
    out[out_base + plane + i] = f[1];
    out[out_base + 2 * plane + i] = f[2];
#endif
}
#endif

/* ari_box_apply: the coefficient sums across the lines (radius r = ARI_R; the shared box filter has
 * summed them along the lines: along x for ARI_DIR 0, along y for 1) and the tentative estimates. coef: the along-summed coefficient planes
 * (a view with a plane stride). ARI_PAIR (step 1, 12 planes): at a pixel of line set s,
 * t_g = (A_g c + B_g) / (W_g + reg), t_c = (A_c g + B_c) / (W_c + reg), guides c (xs view) and g
 * (ys view); out planes t_g, t_c. Else (3 planes): t = (A x + B) / (W + reg), out 1 plane.
 * Halo r across the lines. */
#ifdef ARI_WITH_ari_box_apply
__kernel void ari_box_apply(__global const float *restrict coef, const int coef_base, const int coef_pitch,
                            const int coef_plane,
                            __global const float *restrict xs, const int xs_base, const int xs_pitch,
                            __global const float *restrict ys, const int ys_base, const int ys_pitch,
                            __global float *restrict out, const int w, const int h, const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
#if ARI_DIR == 0
    const int step = coef_pitch;
#else
    const int step = 1;
#endif
    __global const float *k = coef + coef_base + y * coef_pitch + x;
    const float xv = xs[xs_base + y * xs_pitch + x];
#if ARI_PAIR
    float acc[12] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
#pragma unroll
    for (int j = -ARI_R; j <= ARI_R; ++j)
#pragma unroll
        for (int t = 0; t < 12; ++t)
            acc[t] += k[t * coef_plane + j * step];
#if ARI_DIR == 0
    const int set = (y + py) & 1;
#else
    const int set = (x + px) & 1;
#endif
    const float yv = ys[ys_base + y * ys_pitch + x];
    const float ag = set ? acc[6] : acc[0], bg = set ? acc[7] : acc[1], wg = set ? acc[8] : acc[2];
    const float ac = set ? acc[9] : acc[3], bc = set ? acc[10] : acc[4], wc = set ? acc[11] : acc[5];
    out[y * w + x] = (ag * xv + bg) / (wg + ARI_WEIGHT_REG);
    out[w * h + y * w + x] = (ac * yv + bc) / (wc + ARI_WEIGHT_REG);
#else
    float a = 0.0f, b = 0.0f, wt = 0.0f;
#pragma unroll
    for (int j = -ARI_R; j <= ARI_R; ++j) {
        a += k[j * step];
        b += k[coef_plane + j * step];
        wt += k[2 * coef_plane + j * step];
    }
    out[y * w + x] = (a * xv + b) / (wt + ARI_WEIGHT_REG);
#endif
}
#endif

/* ari_green_residual: the new lines of one step-1 iteration along d = (sy, sx): residuals
 * raw - t at the G (chroma) sites interpolated with [1/2, 1, 1/2] along d and added to the tentative
 * estimate; out planes g = G sites ? raw : t_g + r_g, c = G sites ? t_c + r_c : raw. Halo 1 along d. */
#ifdef ARI_WITH_ari_green_residual
__kernel void ari_green_residual(__global const float *restrict raw, const int raw_base, const int raw_pitch,
                                 __global const float *restrict tg, const int tg_base, const int tg_pitch,
                                 __global const float *restrict tc, const int tc_base, const int tc_pitch,
                                 __global float *restrict out, const int w, const int h, const int sy, const int sx,
                                 const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int ra = raw_base + y * raw_pitch + x, ga = tg_base + y * tg_pitch + x;
    const int ca = tc_base + y * tc_pitch + x;
    const int rs = sy * raw_pitch + sx, gs = sy * tg_pitch + sx, cs = sy * tc_pitch + sx;
    const int green = ari_is_green(y, x, py, px);
    const float mg = green ? 1.0f : 0.0f;             /* G at the centre; the two neighbours are the other */
    const float e0g = raw[ra] - tg[ga], e0c = raw[ra] - tc[ca];
    const float emg = raw[ra - rs] - tg[ga - gs], epg = raw[ra + rs] - tg[ga + gs];
    const float emc = raw[ra - rs] - tc[ca - cs], epc = raw[ra + rs] - tc[ca + cs];
    const float r_g = mg * e0g + (1.0f - mg) * (0.5f * emg + 0.5f * epg);
    const float r_c = (1.0f - mg) * e0c + mg * (0.5f * emc + 0.5f * epc);
    out[y * w + x] = green ? raw[ra] : tg[ga] + r_g;
    out[w * h + y * w + x] = green ? tc[ca] + r_c : raw[ra];
}
#endif

/* ari_err_terms: the unsmoothed criterion terms of two fits, errors e_k = u_k - t_k (times the chroma
 * site mask with ARI_REGION: step 2): plane 0 = |e_1| + |e_2|, plane 1 = |e_1(+d) - e_1(-d)| +
 * |e_2(+d) - e_2(-d)| (the [-1, 0, 1] gradient along d = (ARI_SY, ARI_SX)). Halo 1 along d. */
#ifdef ARI_WITH_ari_err_terms
__kernel void ari_err_terms(__global const float *restrict u1, const int u1_base, const int u1_pitch,
                            __global const float *restrict t1, const int t1_base, const int t1_pitch,
                            __global const float *restrict u2, const int u2_base, const int u2_pitch,
                            __global const float *restrict t2, const int t2_base, const int t2_pitch,
                            __global float *restrict out, const int w, const int h, const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    float e1[3], e2[3];
#pragma unroll
    for (int k = -1; k <= 1; ++k) {
        const int yy = y + k * ARI_SY, xx = x + k * ARI_SX;
#if ARI_REGION
        const float m = ari_site(SITE_C, yy, xx, py, px);
#else
        const float m = 1.0f;
#endif
        e1[k + 1] = (u1[u1_base + yy * u1_pitch + xx] - t1[t1_base + yy * t1_pitch + xx]) * m;
        e2[k + 1] = (u2[u2_base + yy * u2_pitch + xx] - t2[t2_base + yy * t2_pitch + xx]) * m;
    }
    out[y * w + x] = __builtin_fabsf(e1[1]) + __builtin_fabsf(e2[1]);
    out[w * h + y * w + x] = __builtin_fabsf(e1[2] - e1[0]) + __builtin_fabsf(e2[2] - e2[0]);
}
#endif

/* ari_gauss_x: the criterion's 5-tap Gaussian (weights k0 centre, k1, k2) along x of the 2 planes of
 * the view src (with a plane stride). ARI_REGION (step 2): a third plane, the same smoothing of
 * the chroma site mask. Halo 2 along x. */
#ifdef ARI_WITH_ari_gauss_x
__kernel void ari_gauss_x(__global const float *restrict src, const int src_base, const int src_pitch,
                          const int src_plane,
                          __global float *restrict out, const int w, const int h, const float k0, const float k1,
                          const float k2, const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    __global const float *s0 = src + src_base + y * src_pitch + x, *s1 = s0 + src_plane;
    out[y * w + x] = k2 * (s0[-2] + s0[2]) + k1 * (s0[-1] + s0[1]) + k0 * s0[0];
    out[w * h + y * w + x] = k2 * (s1[-2] + s1[2]) + k1 * (s1[-1] + s1[1]) + k0 * s1[0];
#if ARI_REGION
    /* the chroma sites alternate along every row: taps at even offsets share the centre's kind, odd
     * ones that of x + 1 */
    const float mc = ari_site(SITE_C, y, x, py, px), mo = ari_site(SITE_C, y, x + 1, py, px);
    out[2 * w * h + y * w + x] = 2.0f * k2 * mc + 2.0f * k1 * mo + k0 * mc;
#endif
}
#endif

/* ari_gauss_y: the same along y, then (ARI_REGION) each plane divided by the smoothed mask and
 * multiplied by the mask (reference._criterion's normalisation). Out planes: smoothed c, smoothed g.
 * Halo 2 along y. */
#ifdef ARI_WITH_ari_gauss_y
__kernel void ari_gauss_y(__global const float *restrict src, const int src_base, const int src_pitch,
                          const int src_plane,
                          __global float *restrict out, const int w, const int h, const float k0, const float k1,
                          const float k2, const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    __global const float *s0 = src + src_base + y * src_pitch + x, *s1 = s0 + src_plane;
    float a0 = k2 * (s0[-2 * src_pitch] + s0[2 * src_pitch]) + k1 * (s0[-src_pitch] + s0[src_pitch]) + k0 * s0[0];
    float a1 = k2 * (s1[-2 * src_pitch] + s1[2 * src_pitch]) + k1 * (s1[-src_pitch] + s1[src_pitch]) + k0 * s1[0];
#if ARI_REGION
    __global const float *s2 = s1 + src_plane;
    const float a2 = k2 * (s2[-2 * src_pitch] + s2[2 * src_pitch]) + k1 * (s2[-src_pitch] + s2[src_pitch]) + k0 * s2[0];
    const float m = ari_site(SITE_C, y, x, py, px);
    a0 = a0 / a2 * m;
    a1 = a1 / a2 * m;
#endif
    out[y * w + x] = a0;
    out[w * h + y * w + x] = a1;
}
#endif

/* ari_select: one iteration's selection: criterion c^2 g from the smoothed terms (planes c, g of the
 * view crit), at least ARI_CRIT_FLOOR (below it criteria are rounding: ties); where it is below the
 * best so far (always on the ``first`` iteration) the estimates become the new values n1, n2 (views),
 * else the previous ones (planes estimate 1, estimate 2, best criterion of the view prev). Out planes
 * estimate 1, estimate 2, best criterion. Halo 0. */
#ifdef ARI_WITH_ari_select
__kernel void ari_select(__global const float *restrict crit, const int crit_base, const int crit_pitch,
                         const int crit_plane,
                         __global const float *restrict n1, const int n1_base, const int n1_pitch,
                         __global const float *restrict n2, const int n2_base, const int n2_pitch,
                         __global const float *restrict prev, const int prev_base, const int prev_pitch,
                         const int prev_plane,
                         __global float *restrict out, const int w, const int h, const int first)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int ci = crit_base + y * crit_pitch + x;
    const float c = crit[ci], g = crit[crit_plane + ci];
    const float cr = fmax(c * c * g, ARI_CRIT_FLOOR);
    const float v1 = n1[n1_base + y * n1_pitch + x], v2 = n2[n2_base + y * n2_pitch + x];
    const int i = y * w + x, plane = w * h;
    if (first) {
        out[i] = v1;
        out[plane + i] = v2;
        out[2 * plane + i] = cr;
    } else {
        const int pi = prev_base + y * prev_pitch + x;
        const float best = prev[2 * prev_plane + pi];
        const int better = cr < best;
        out[i] = better ? v1 : prev[pi];
        out[plane + i] = better ? v2 : prev[prev_plane + pi];
        out[2 * plane + i] = better ? cr : best;
    }
}
#endif

/* The four (direction, kind) estimates of a merge: ARI_EST_ARGS(k) declares the view est<k> (est<k>,
 * est<k>_base, est<k>_pitch, est<k>_plane) of one ari_select output (planes: estimate 1, estimate 2,
 * best criterion). ARI_MEAN4(var, pl): float var = the criterion-weighted mean of plane pl of est0..est3,
 * sum w e / sum w with w = 1 / (criterion + ARI_CRIT_REG) (reference._adaptive). */
#define ARI_EST_ARGS(k) __global const float *restrict est##k, const int est##k##_base, const int est##k##_pitch, \
                        const int est##k##_plane
#define ARI_ADAPT(k, pl) { const int at = est##k##_base + y * est##k##_pitch + x; \
                          const float wt = 1.0f / (est##k[2 * est##k##_plane + at] + ARI_CRIT_REG); \
                          num += wt * est##k[(pl) * est##k##_plane + at]; den += wt; }
#define ARI_MEAN4(var, pl) float var; { float num = 0.0f, den = 0.0f; \
                           ARI_ADAPT(0, pl) ARI_ADAPT(1, pl) ARI_ADAPT(2, pl) ARI_ADAPT(3, pl) var = num / den; }

/* ari_green_merge: G = raw at G sites, else the criterion-weighted mean of the four (direction, kind)
 * G estimates (plane 0 of est0..est3). Halo 0. */
#ifdef ARI_WITH_ari_green_merge
__kernel void ari_green_merge(ARI_EST_ARGS(0), ARI_EST_ARGS(1), ARI_EST_ARGS(2), ARI_EST_ARGS(3),
                              __global const float *restrict raw, const int raw_base, const int raw_pitch,
                              __global float *restrict out, const int w, const int h, const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    ARI_MEAN4(g, 0)
    out[y * w + x] = ari_is_green(y, x, py, px) ? raw[raw_base + y * raw_pitch + x] : g;
}
#endif

/* ari_chroma_start: the start of one plane of steps 2 / 3 along d = (sy, sx): values v = ARI_KNOWN sites
 * ? src : 0; out = ARI_TARGET sites ? mean of v at the two neighbours along d : v. Halo 1 along d. */
#ifdef ARI_WITH_ari_chroma_start
__kernel void ari_chroma_start(__global const float *restrict src, const int src_base, const int src_pitch,
                               __global float *restrict out, const int w, const int h, const int sy, const int sx,
                               const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int at = src_base + y * src_pitch + x, s = sy * src_pitch + sx;
    const float vm = ari_site(ARI_KNOWN, y - sy, x - sx, py, px) * src[at - s];
    const float vp = ari_site(ARI_KNOWN, y + sy, x + sx, py, px) * src[at + s];
    const float v = ari_site(ARI_KNOWN, y, x, py, px) * src[at];
    out[y * w + x] = ari_site(ARI_TARGET, y, x, py, px) != 0.0f ? 0.5f * vm + 0.5f * vp : v;
}
#endif

/* ari_chroma_residual: one plane's new values of a step 2 / 3 iteration: residual (v - t) at the ARI_KNOWN
 * sites (v = known ? src : 0) interpolated with [1/2, 0, 1/2] along d; out = ARI_TARGET ? t + residual : v.
 * Halo 1 along d. */
#ifdef ARI_WITH_ari_chroma_residual
__kernel void ari_chroma_residual(__global const float *restrict src, const int src_base, const int src_pitch,
                                  __global const float *restrict t, const int t_base, const int t_pitch,
                                  __global float *restrict out, const int w, const int h, const int sy, const int sx,
                                  const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    const int at = src_base + y * src_pitch + x, s = sy * src_pitch + sx;
    const int ta = t_base + y * t_pitch + x, st = sy * t_pitch + sx;
    const float rm = ari_site(ARI_KNOWN, y - sy, x - sx, py, px) * (src[at - s] - t[ta - st]);
    const float rpl = ari_site(ARI_KNOWN, y + sy, x + sx, py, px) * (src[at + s] - t[ta + st]);
    const float v = ari_site(ARI_KNOWN, y, x, py, px) * src[at];
    out[y * w + x] = ari_site(ARI_TARGET, y, x, py, px) != 0.0f ? t[ta] + (0.5f * rm + 0.5f * rpl) : v;
}
#endif

/* ari_diag_coefficients: the weighted fit of target y (view) from guide x (view) over the chroma
 * sites of the diagonal window {(i + j, i - j): |i| <= p = ARI_P, |j| <= q = ARI_Q} (step 2): centred moments summed
 * directly (the window's sites are all chroma sites or all G sites, the latter giving the empty fit
 * a = b = 0, w = 1 / floor), ARI_MLRI: slope from the Laplacians along d = (1, ARI_LS) ([-1, 0, 2, 0, -1])
 * over the ARI_KNOWN sites. Out planes a w, b w, w. Halo p + q (+ 2 with ARI_MLRI). */
#ifdef ARI_WITH_ari_diag_coefficients
__kernel void ari_diag_coefficients(__global const float *restrict xs, const int xs_base, const int xs_pitch,
                                    __global const float *restrict ys, const int ys_base, const int ys_pitch,
                                    __global float *restrict out, const int w, const int h, const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    __global const float *xc = xs + xs_base + y * xs_pitch + x, *yc = ys + ys_base + y * ys_pitch + x;
    const float cx = xc[0], cy = yc[0];
    const float m = ari_site(SITE_C, y, x, py, px);
    float n = 0.0f, sd = 0.0f, se = 0.0f, sdd = 0.0f, see = 0.0f, sde = 0.0f;
#if ARI_MLRI
    float l_xy = 0.0f, l_xx = 0.0f, l_n = 0.0f;
    const int lxs = 2 * (xs_pitch + ARI_LS), lys = 2 * (ys_pitch + ARI_LS);
#endif
#pragma unroll
    for (int i = -ARI_P; i <= ARI_P; ++i)
#pragma unroll
        for (int j = -ARI_Q; j <= ARI_Q; ++j) {
            const int dy = i + j, dx = i - j;
            const float xv = xc[dy * xs_pitch + dx], yv = yc[dy * ys_pitch + dx];
            const float d = m * (xv - cx), e = m * (yv - cy);
            sd += d;
            se += e;
            sdd += d * d;
            see += e * e;
            sde += d * e;
#if ARI_MLRI
            const float lm = ari_site(ARI_KNOWN, y + dy, x + dx, py, px);
            const float lx = 2.0f * xv - xc[dy * xs_pitch + dx - lxs] - xc[dy * xs_pitch + dx + lxs];
            const float ly = 2.0f * yv - yc[dy * ys_pitch + dx - lys] - yc[dy * ys_pitch + dx + lys];
            l_xy += lm * lx * ly;
            l_xx += lm * lx * lx;
            l_n += lm;
#endif
        }
    n = m * (float)((2 * ARI_P + 1) * (2 * ARI_Q + 1));        /* not summed in the loop: see below */
    ari_moments mo = {n, sd, se, sdd, see, sde};
    float mean_x, mean_y, var_x, var_y, cov;
#if ARI_MLRI
    /* one division for 1 / max(n, 1) and the slope (l_xy / ln) / (l_xx / ln + eps) = l_xy / (l_xx + eps ln),
     * ln = max(l_n, 1): two would be SLP-packed into a <2 x float> division, which keeps PoCL from
     * vectorising the kernel across work-items */
    const float nn = n > 1.0f ? n : 1.0f, ln = l_n > 1.0f ? l_n : 1.0f;
    const float den = l_xx + ARI_EPS * ln, r = 1.0f / (nn * den);
    ari_stats_inv(&mo, den * r, cx, cy, &mean_x, &mean_y, &var_x, &var_y, &cov);
    const float a = l_xy * nn * r;
#else
    ari_stats(&mo, cx, cy, &mean_x, &mean_y, &var_x, &var_y, &cov);
    const float a = cov / (var_x + ARI_EPS);
#endif
    float f[3];
    ari_fit_values(a, mean_x, mean_y, var_x, var_y, cov, f);
    out[y * w + x] = f[0];
    out[w * h + y * w + x] = f[1];
    out[2 * w * h + y * w + x] = f[2];
}
#endif

/* ari_diag_apply: t = (A x + B) / (W + reg), A, B, W the sums of the 3 coefficient planes (the view
 * coef) over the diagonal window (ARI_P, ARI_Q); x the guide (the view xs). Halo p + q. */
#ifdef ARI_WITH_ari_diag_apply
__kernel void ari_diag_apply(__global const float *restrict coef, const int coef_base, const int coef_pitch,
                             const int coef_plane,
                             __global const float *restrict xs, const int xs_base, const int xs_pitch,
                             __global float *restrict out, const int w, const int h)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    __global const float *k = coef + coef_base + y * coef_pitch + x;
    float a = 0.0f, b = 0.0f, wt = 0.0f;
#pragma unroll
    for (int i = -ARI_P; i <= ARI_P; ++i)
#pragma unroll
        for (int j = -ARI_Q; j <= ARI_Q; ++j) {
            const int o = (i + j) * coef_pitch + (i - j);
            a += k[o];
            b += k[coef_plane + o];
            wt += k[2 * coef_plane + o];
        }
    out[y * w + x] = (a * xs[xs_base + y * xs_pitch + x] + b) / (wt + ARI_WEIGHT_REG);
}
#endif

/* ari_rb_merge: R and B after step 2: red = R sites ? raw : B sites ? the criterion-weighted mean of
 * the four R estimates (plane 0 of est0..est3) : 0; blue likewise (plane 1, R and B swapped). Out planes
 * red, blue. Halo 0. */
#ifdef ARI_WITH_ari_rb_merge
__kernel void ari_rb_merge(ARI_EST_ARGS(0), ARI_EST_ARGS(1), ARI_EST_ARGS(2), ARI_EST_ARGS(3),
                           __global const float *restrict raw, const int raw_base, const int raw_pitch,
                           __global float *restrict out, const int w, const int h, const int py, const int px)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    ARI_MEAN4(r_at_b, 0)
    ARI_MEAN4(b_at_r, 1)
    const float v = raw[raw_base + y * raw_pitch + x];
    const float is_r = ari_site(SITE_R, y, x, py, px), is_b = ari_site(SITE_B, y, x, py, px);
    out[y * w + x] = is_r != 0.0f ? v : is_b != 0.0f ? r_at_b : 0.0f;
    out[w * h + y * w + x] = is_b != 0.0f ? v : is_r != 0.0f ? b_at_r : 0.0f;
}
#endif

/* ari_final: the stage's output planes R, G, B (times ``scale``, back to the mosaic's units): at G
 * sites R and B are the criterion-weighted means of the four step-3 estimates (planes 0, 1 of
 * est0..est3), elsewhere the step-2 planes (the view rb); G from the view green. Each role goes to
 * the output plane of its CFA channel (plane_r, plane_g, plane_b: 0, 1, 2 on RGB Bayer; L doubled
 * on the Bayer layout writes its G role to plane 0). Halo 0. */
#ifdef ARI_WITH_ari_final
__kernel void ari_final(ARI_EST_ARGS(0), ARI_EST_ARGS(1), ARI_EST_ARGS(2), ARI_EST_ARGS(3),
                        __global const float *restrict rb, const int rb_base, const int rb_pitch, const int rb_plane,
                        __global const float *restrict green, const int green_base, const int green_pitch,
                        __global float *restrict out, const int w, const int h, const int py, const int px,
                        const float scale, const int plane_r, const int plane_g, const int plane_b)
{
    const int x = inward_id(0, w - 1), y = inward_id(1, h - 1);
    ARI_MEAN4(r_at_g, 0)
    ARI_MEAN4(b_at_g, 1)
    const int g_site = ari_is_green(y, x, py, px);
    const int at = rb_base + y * rb_pitch + x;
    out[plane_r * w * h + y * w + x] = (g_site ? r_at_g : rb[at]) * scale;
    out[plane_g * w * h + y * w + x] = green[green_base + y * green_pitch + x] * scale;
    out[plane_b * w * h + y * w + x] = (g_site ? b_at_g : rb[rb_plane + at]) * scale;
}
#endif
