/* LMS hybrid demosaic (paper Fig. 5): one kernel per algorithm step, in run order;
 * NumPy twins of the same names in clisp/modules/demosaic_lms/stage.py.
 * Defines from the host: CFA_PERIOD; CH_L, CH_M, CH_S (channel indices of the CFA description);
 * SELECT (0 soft, 1 hard, 2 iso: step A direction choice); NOISY (0: noiseless, eps constant);
 * LUM_R (h_lum radius); CHROMA_R (radius of the chroma binomial);
 * BL_R, BL_RATIO (bilateral option radius; 1: interpolate S/I, 0: S - I); MAX_SITES (longest list
 * of S-site offsets, for s_joint_bilateral). Host-generated: LUM_SUPPORT (see luma_lowpass).
 * Step C's default, the masked guided filter, runs the kernels of guided_filter.cl (shared with the
 * guided LMS demosaic); this file holds its bilateral option.
 * Geometry: every kernel writes an out_w x out_h image; "at" arguments give the pixel of an input
 * that output pixel (0, 0) is centred on; (oy, ox) are image coordinates (CFA phase) of a pixel. */

/* No kernel checks bounds: the host launches whole work-groups only and covers a ragged right or
 * bottom edge by shifting the last launch inward (those work-items recompute identical values), see
 * runtime.launch_exact. With no control flow in its body PoCL vectorises a kernel across
 * work-items (an 81-tap luma_lowpass on 6 MP: 364 ms with a bounds check, 24 ms without). Hence also
 * branch-free bodies: selections, not ifs. */

/* Maths written as selects: this PoCL build calls fabs, fmax, sqrt and exp per work-item instead of
 * vectorising them (m_at_s on 6 MP: 60 ms with fabs, 8 ms with the select below). */
inline float abs_f(const float a) { return a < 0.0f ? -a : a; }
inline float max_f(const float a, const float b) { return a > b ? a : b; }

#define SELECT_SOFT 0
#define SELECT_HARD 1

/* CFA phase index py * P + px of image pixel (y, x) (y, x may be negative). */
inline int cfa_phase(const int y, const int x)
{
    return (((y % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD) * CFA_PERIOD
         + ((x % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD;
}

/* m_at_s (step A): the L/M quincunx mosaic. m(y, x) = p(y+2, x+2) except at S sites, where it is
 * the edge-directed M estimate: E_h, E_v, E_d1, E_d2 (means of the M pairs on each line) mixed by
 * weights 1/(eps + G)^2 (soft), taken at the smallest G (hard) or the diagonal mean (iso), plus
 * s_detail * (S - mean of the four S at (+-2, +-2)). eps = eps0 + eps_sigma * sigma, sigma^2 =
 * shot_m * level + floor_m at the diagonal-mean level. Halo 2. (oy, ox): image pixel of p(0, 0). */
__kernel void m_at_s(__global const float *restrict p, __global float *restrict m, const int in_w, const int out_w,
                     const int out_h, const int oy, const int ox, __constant const char *restrict pattern,
                     const float eps0, const float eps_sigma, const float s_detail,
                     const float shot_m, const float floor_m)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    __global const float *c = p + (y + 2) * in_w + (x + 2);
    const float centre = c[0];
#define P(dy, dx) c[(dy) * in_w + (dx)]
    const float e_h = 0.5f * (P(0, -2) + P(0, 2));
    const float e_v = 0.5f * (P(-2, 0) + P(2, 0));
    const float e_d1 = 0.5f * (P(-1, -1) + P(1, 1));
    const float e_d2 = 0.5f * (P(-1, 1) + P(1, -1));
    const float iso = 0.5f * (e_d1 + e_d2);
#if SELECT == SELECT_SOFT || SELECT == SELECT_HARD
    const float g_h = abs_f(P(0, -2) - P(0, 2)) + abs_f(P(0, -1) - P(0, 1));
    const float g_v = abs_f(P(-2, 0) - P(2, 0)) + abs_f(P(-1, 0) - P(1, 0));
    const float g_d1 = 2.0f * abs_f(P(-1, -1) - P(1, 1));
    const float g_d2 = 2.0f * abs_f(P(-1, 1) - P(1, -1));
#endif
#if SELECT == SELECT_SOFT
#if NOISY
    const float eps = eps0 + eps_sigma * sqrt(shot_m * max_f(iso, 0.0f) + floor_m);
#else
    const float eps = eps0;                     /* noiseless: sigma = 0, and no sqrt per pixel */
#endif
    const float w_h = 1.0f / ((eps + g_h) * (eps + g_h));
    const float w_v = 1.0f / ((eps + g_v) * (eps + g_v));
    const float w_d1 = 1.0f / ((eps + g_d1) * (eps + g_d1));
    const float w_d2 = 1.0f / ((eps + g_d2) * (eps + g_d2));
    float est = (w_h * e_h + w_v * e_v + w_d1 * e_d1 + w_d2 * e_d2) / (w_h + w_v + w_d1 + w_d2);
#elif SELECT == SELECT_HARD
    float est = e_h, g = g_h;                   /* first smallest gradient in the order h, v, d1, d2 */
    est = g_v < g ? e_v : est;
    g = g_v < g ? g_v : g;
    est = g_d1 < g ? e_d1 : est;
    g = g_d1 < g ? g_d1 : g;
    est = g_d2 < g ? e_d2 : est;
#else
    float est = iso;
#endif
    est += s_detail * (centre - 0.25f * (P(-2, -2) + P(-2, 2) + P(2, -2) + P(2, 2)));
#undef P
    m[y * out_w + x] = cfa_channel(pattern, y + 2 + oy, x + 2 + ox) == CH_S ? est : centre;
}

/* luma_lowpass (step B): lum = h_lum * m. Weights from the host (h_lum's non-zero taps in row
 * order); which taps are non-zero is structure (the diamond filter vanishes at even offsets, the
 * notch outside 5 x 5), so the host generates LUM_SUPPORT = X(dy, dx, t) for each such tap t and
 * structural zeros cost nothing (6 MP: 24 ms against 39 ms for all 81 taps). Halo LUM_R. */
__kernel void luma_lowpass(__global const float *restrict m, __global float *restrict lum, const int in_w, const int out_w,
                           const int out_h, __constant const float *restrict weight)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    __global const float *c = m + (y + LUM_R) * in_w + (x + LUM_R);
    float acc = 0.0f;
#define X(dy, dx, t) acc += weight[t] * c[(dy) * in_w + (dx)];
    LUM_SUPPORT
#undef X
    lum[y * out_w + x] = acc;
}

/* chroma_demodulate_rows (step B, chroma first half): rows(y, x) = sum_k g[k] d(Y, X+k) mod(Y, X+k),
 * d = m - lum, (Y, X) = (y + at_y, x + at_x) in lum; mod = +1 at L sites, -1 elsewhere, which
 * alternates along a row. m is lum's window grown by LUM_R; (oy, ox): image pixel of lum(0, 0).
 * Reads lum +-CHROMA_R along x. */
__kernel void chroma_demodulate_rows(__global const float *restrict m, __global const float *restrict lum,
                                     __global float *restrict rows, const int m_w, const int lum_w,
                                     const int out_w, const int out_h, const int at_y, const int at_x,
                                     const int oy, const int ox, __constant const char *restrict pattern,
                                     __constant const float *restrict g)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int yy = y + at_y, xx = x + at_x;
    __global const float *lc = lum + yy * lum_w + xx;
    __global const float *mc = m + (yy + LUM_R) * m_w + (xx + LUM_R);
    float acc = 0.0f, sign = 1.0f;
    #pragma unroll
    for (int k = -CHROMA_R; k <= CHROMA_R; ++k) {
        acc += sign * g[k + CHROMA_R] * (mc[k] - lc[k]);
        sign = -sign;
    }
    /* sign of tap k = -CHROMA_R is (-1)^CHROMA_R times the centre's */
    const float centre_mod = cfa_channel(pattern, yy + oy, xx + ox) == CH_L ? 1.0f : -1.0f;
    rows[y * out_w + x] = ((CHROMA_R & 1) ? -centre_mod : centre_mod) * acc;
}

/* lm_combine (step B, chroma second half + combination): chr = sum_k g[k] rows(y + CHROMA_R + k, x);
 * L = lum + chr into plane 0, M = lum - chr into plane 1 of dst; lum centre at (y + at_y, x + at_x).
 * Reads rows +-CHROMA_R along y. */
__kernel void lm_combine(__global const float *restrict lum, __global const float *restrict rows, __global float *restrict dst,
                         const int lum_w, const int rows_w, const int out_w, const int out_h,
                         const int at_y, const int at_x, __constant const float *restrict g)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    __global const float *rc = rows + (y + CHROMA_R) * rows_w + x;
    float chr = 0.0f;
    #pragma unroll
    for (int k = -CHROMA_R; k <= CHROMA_R; ++k)
        chr += g[k + CHROMA_R] * rc[k * rows_w];
    const float l = lum[(y + at_y) * lum_w + x + at_x];
    const int i = y * out_w + x;
    dst[i] = l + chr;
    dst[out_w * out_h + i] = l - chr;
}

/* s_joint_bilateral (step C option): S = I * sum w v / sum w (BL_RATIO: v = S / max(I, floor)) or
 * I + sum w v / sum w (v = S - I) over the S sites within BL_R (per-phase site
 * lists from the host), w = exp(e - max e), e = -d^2 inv_2ss - (I_q - I)^2 / (2 sigma_r^2)
 * (shifting by the largest exponent keeps the best site's weight at 1, so no window underflows to
 * 0/0), sigma_r = max(sr_min, sr_k * std of lum), var(lum) = lum_shot * I + lum_floor. Into plane 2
 * of dst. Centres: lum (y + at_y, x + at_x), p (y + p_y, x + p_x); (oy, ox): image pixel of output
 * (0, 0). Halo BL_R. */
__kernel void s_joint_bilateral(__global const float *restrict lum, __global const float *restrict p, __global float *restrict dst,
                                const int lum_w, const int p_w, const int out_w, const int out_h,
                                const int at_y, const int at_x, const int p_y, const int p_x,
                                const int oy, const int ox, __constant const int2 *restrict site,
                                __constant const float *restrict site_w, const float inv_2ss, const float sr_k,
                                const float sr_min, const float ratio_floor, const float lum_shot,
                                const float lum_floor)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int phase = cfa_phase(y + oy, x + ox);
    __constant const int2 *s = site + phase * MAX_SITES;
    __constant const float *sw = site_w + phase * MAX_SITES;
    __global const float *lc = lum + (y + at_y) * lum_w + x + at_x;
    __global const float *pc = p + (y + p_y) * p_w + x + p_x;
    const float guide = lc[0];
    const float sigma_r = max_f(sr_min, sr_k * sqrt(lum_shot * max_f(guide, 0.0f) + lum_floor));
    const float inv_2sr = 1.0f / (2.0f * sigma_r * sigma_r);
    float e[MAX_SITES], v[MAX_SITES];
    float e_max = -INFINITY;
    #pragma unroll
    for (int k = 0; k < MAX_SITES; ++k) {
        const int dy = s[k].x, dx = s[k].y;
        const float gq = lc[dy * lum_w + dx];
        const float sq = pc[dy * p_w + dx];
        const float ek = -(float)(dy * dy + dx * dx) * inv_2ss - (gq - guide) * (gq - guide) * inv_2sr;
        e[k] = sw[k] > 0.0f ? ek : -INFINITY;
        e_max = max_f(e_max, e[k]);
#if BL_RATIO
        v[k] = sq / max_f(gq, ratio_floor);
#else
        v[k] = sq - gq;
#endif
    }
    float num = 0.0f, den = 0.0f;
    #pragma unroll
    for (int k = 0; k < MAX_SITES; ++k) {
        const float w = exp(e[k] - e_max);
        num += w * v[k];
        den += w;
    }
#if BL_RATIO
    dst[2 * out_w * out_h + y * out_w + x] = guide * (num / den);
#else
    dst[2 * out_w * out_h + y * out_w + x] = guide + num / den;
#endif
}
