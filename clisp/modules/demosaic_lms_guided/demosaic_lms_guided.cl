/* Guided LMS demosaic (issue 3): one kernel per algorithm step, in run order; NumPy twins of the same
 * names in clisp/modules/demosaic_lms_guided/stage.py. Its guided filters (M at S, chroma, S) run the kernels of
 * guided_filter.cl.
 *
 * Defines from the host:
 *   L_PAR, S_Y, S_D  the CFA (checked by check_lms_structure): L iff x + y + L_PAR is even; S iff
 *                    y + S_Y is even and x - y + S_D is a multiple of 4; M otherwise (image coordinates;
 *                    at_l, at_s in common.h)
 *   NOISY            0: noiseless, every LMMSE gain is 1 and no noise term is computed
 *   TONE_POWER       exponent of the tonality in tonal() (clisp TONE_POWER)
 *   D_RADIUS, PRE_RADIUS, COMBINE_RADIUS, RI_RADIUS, BP_RADIUS, HP_RADIUS, S_ALIAS_RADIUS
 *                    the radii of the steps (stage.py's constants of the same names): the diamond D,
 *                    the chroma pre-filter B5, the 5 x 5 means of the combine steps, the S tent, the
 *                    half-Nyquist band-pass (taps at even offsets), the axial high-pass, s_alias
 * Host-generated: D_TAPS, the off-centre support of the 9 x 9 diamond half-band D, and TENT_TAPS, the
 * support of the 7 x 7 residual-interpolation tent, as X(dy, dx, t) (weights in constant buffers).
 *
 * Geometry: a kernel writes an out_w x out_h image (planes of out_w * out_h); output pixel (y, x) is
 * centred on pixel (y + R, x + R) of the kernel's own window (R: the kernel's radius); inputs on larger
 * windows get offsets (*_off) added to own-window coordinates; (oy, ox) are the image coordinates of
 * own-window pixel (0, 0). All maths float32; weights and parameters come from the host.
 *
 * No kernel checks bounds: the host launches whole work-groups only and covers a ragged right or
 * bottom edge by shifting the last launch inward (those work-items recompute identical values), see
 * runtime.launch_exact. Bodies are branch-free (selects) with compile-time loop bounds, which
 * PoCL unrolls and vectorises across work-items. */

#if BP_RADIUS != 2 * COMBINE_RADIUS || S_ALIAS_RADIUS != 2 * COMBINE_RADIUS
#error "lm_energy and s_alias share loops: BP_RADIUS and S_ALIAS_RADIUS must be 2 COMBINE_RADIUS"
#endif
#define COMBINE_SIDE (2 * COMBINE_RADIUS + 1)
#define COMBINE_AREA (COMBINE_SIDE * COMBINE_SIDE)

inline float max_f(const float a, const float b) { return a > b ? a : b; }
inline float min_f(const float a, const float b) { return a < b ? a : b; }

/* e_band tau^TONE_POWER, tau = min(e_band / e_ac, 1) (0 where e_ac == 0): the band's share of the local
 * detail energy (its tonality) weighting the band energy. */
inline float tonal(const float e_band, const float e_ac)
{
    const float tau = e_ac > 0.0f ? min_f(e_band / e_ac, 1.0f) : 0.0f;
    float w = e_band;
    #pragma unroll
    for (int i = 0; i < TONE_POWER; ++i)       /* multiplications, not pown: pown stops PoCL vectorising */
        w *= tau;
    return w;
}

/* The shrink max(energy - alias, 0) / energy of a chroma deviation of energy `energy` of which `alias`
 * is expected to be luminance aliased onto a chroma carrier; 1 where energy == 0. */
inline float alias_gain(const float energy, const float alias)
{
    return energy > 0.0f ? max_f(energy - alias, 0.0f) / energy : 1.0f;
}

/* The (pi, pi) carrier: +1 at L sites, -1 elsewhere (at_l: common.h, from the defines L_PAR, S_Y, S_D). */
inline float mod_f(const int y, const int x) { return at_l(y, x) ? 1.0f : -1.0f; }

/* The off-centre taps of the diamond D (D_SUM's literal weights) around c, a pointer to the centre
 * pixel of an image of row pitch in_w. */
__attribute__((always_inline)) inline float d_offcentre(__global const float *restrict c, const int in_w)
{
#define P(dy, dx) c[(dy) * in_w + (dx)]
    return D_SUM(P);
#undef P
}

/* l_guide: I0 = p at L sites; 2 sum_{t != 0} D[t] p(. + t) elsewhere (the off-centre taps of D land
 * on L sites only: the L quincunx interpolated); D's weights are D_SUM's literals (d is unread). R = 4. */
__kernel void l_guide(__global const float *restrict p, __global float *restrict dst, const int in_w, const int out_w,
                      const int oy, const int ox, __constant const float *restrict d, const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    __global const float *c = p + (y + D_RADIUS) * in_w + (x + D_RADIUS);
    const float acc = d_offcentre(c, in_w);
    dst[y * out_w + x] = at_l(y + D_RADIUS + oy, x + D_RADIUS + ox) ? c[0] : 2.0f * acc;
}

/* m_keep: dst = p on the kernel's window (p on a window larger by p_off): the L/M quincunx m outside
 * the S sites, which m_at_s_combine then fills in. R = 0. */
__kernel void m_keep(__global const float *restrict p, __global float *restrict dst, const int p_w, const int p_off,
                     const int out_w, const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    dst[y * out_w + x] = p[(y + p_off) * p_w + x + p_off];
}

/* The lattice seen from an S site, at offset (dy, dx): S iff dy is even and dx - dy a multiple of 4,
 * L iff dy + dx is odd (at_s, at_l with the S site's own parities). Constant offsets fold at compile
 * time: m_at_s_combine runs on S sites only, so its masks need no integer work per tap. */
inline int s_rel(const int dy, const int dx) { return (dy & 1) == 0 && ((dx - dy) & 3) == 0; }
inline int l_rel(const int dy, const int dx) { return ((dy + dx) & 1) != 0; }

/* The S site of work-item (gx, gy) of m_at_s_combine and m_at_s_combine_dir, in output coordinates
 * (*y, *x; image row y + COMBINE_RADIUS + oy): the item takes the S site in output row 2 gy + (row
 * parity) and columns 4 gx .. 4 gx + 3. 0 for an item past the window's edge (out_w x out_h). */
inline int s_site(const int oy, const int ox, const int out_w, const int out_h, int *y, int *x)
{
    *y = 2 * get_global_id(1) + ((COMBINE_RADIUS + oy + S_Y) & 1);
    *x = 4 * get_global_id(0) + ((*y + COMBINE_RADIUS + oy - S_D - COMBINE_RADIUS - ox) & 3);
    return *y < out_h && *x < out_w;
}

/* M at the S site (yc, xc) of the fits' window (width in_w): M = Mfit + gamma (p - Sfit), gamma = 1
 * (noiseless) or sig / (sig + var_S(Sfit)), sig = max(E_M - var_M(Mfit), 0), E_M = mean over the M
 * sites of the 5 x 5 of (p - Mfit)^2; p on a window larger by p_off (width p_w). */
inline float m_at_s_lmmse(__global const float *restrict p, __global const float *restrict mfit,
                          __global const float *restrict sfit, const int yc, const int xc, const int in_w,
                          const int p_w, const int p_off, const float shot_m, const float floor_m,
                          const float shot_s, const float floor_s)
{
    const int ic = yc * in_w + xc;
    const float pc = p[(yc + p_off) * p_w + xc + p_off];
    const float mf = mfit[ic], sf = sfit[ic];
#if NOISY
    float e = 0.0f, cnt = 0.0f;
    #pragma unroll
    for (int dy = -COMBINE_RADIUS; dy <= COMBINE_RADIUS; ++dy) {
        #pragma unroll
        for (int dx = -COMBINE_RADIUS; dx <= COMBINE_RADIUS; ++dx) {
            if (!s_rel(dy, dx) && !l_rel(dy, dx)) {        /* the M sites; compile time (adding 0 * x: no-op) */
                const float rm = p[(yc + dy + p_off) * p_w + xc + dx + p_off] - mfit[ic + dy * in_w + dx];
                e += rm * rm;
                cnt += 1.0f;
            }
        }
    }
    const float sig = max_f(e / cnt - (shot_m * max_f(mf, 0.0f) + floor_m), 0.0f);
    const float gamma = sig / (sig + shot_s * max_f(sf, 0.0f) + floor_s);
    return mf + gamma * (pc - sf);
#else
    return mf + (pc - sf);
#endif
}

/* m_at_s_combine (pass 1): M at the S sites of m (the other pixels are m_keep's p), one work-item per
 * S site (s_site), by m_at_s_lmmse. mfit, sfit on the kernel's window (width in_w); p on a window
 * larger by p_off (width p_w); dst (out_w x out_h) is the window shrunk by R; (oy, ox): image
 * coordinates of the kernel's window pixel (0, 0). R = 2. */
__kernel void m_at_s_combine(__global const float *restrict p, __global const float *restrict mfit, __global const float *restrict sfit,
                             __global float *restrict dst, const int in_w, const int p_w, const int p_off,
                             const int out_w, const int oy, const int ox,
                             const float shot_m, const float floor_m, const float shot_s, const float floor_s,
                             const int out_h)
{
    int y, x;
    if (!s_site(oy, ox, out_w, out_h, &y, &x))
        return;
    dst[y * out_w + x] = m_at_s_lmmse(p, mfit, sfit, y + COMBINE_RADIUS, x + COMBINE_RADIUS, in_w, p_w, p_off,
                                      shot_m, floor_m, shot_s, floor_s);
}

/* m_at_s_combine_dir (pass 2): m_at_s_combine's estimate mixed with the edge-directed estimate yd - c
 * by w = hf / (hf + min_d err_d), hf = kappa * 5 x 5 mean of (y - ylp)^2, err_d the mean squared error
 * of the 2-tap predictor along d at the non-S pixels of the 3 x 3, yd = sum_d E_d / (eps + err_d) /
 * sum_d 1 / (eps + err_d); then alias suppression toward the neutral mn = m_from_s p: dev = est - mn,
 * est = mn + alias_gain(dev^2, alias_m E_sig) dev, E_sig = max(hf / kappa - blend_k vn, 0), vn =
 * lum_shot max(ylp, 0) + lum_floor. Windows as m_at_s_combine's; y and c, ylp on windows larger by
 * y_off, l_off (widths y_w, l_w). R = 2. */
__kernel void m_at_s_combine_dir(__global const float *restrict p, __global const float *restrict mfit,
                                 __global const float *restrict sfit, __global const float *restrict yg,
                                 __global const float *restrict cg, __global const float *restrict ylpg,
                                 __global float *restrict dst, const int in_w, const int p_w, const int p_off,
                                 const int y_w, const int y_off, const int l_w, const int l_off,
                                 const int out_w, const int oy, const int ox,
                                 const float shot_m, const float floor_m, const float shot_s, const float floor_s,
                                 const float kappa, const float dir_eps, const float blend_k,
                                 const float lum_shot, const float lum_floor, const float alias_m,
                                 const float m_from_s, const int out_h)
{
    int y, x;
    if (!s_site(oy, ox, out_w, out_h, &y, &x))
        return;
    const int yc = y + COMBINE_RADIUS, xc = x + COMBINE_RADIUS;
    const float pc = p[(yc + p_off) * p_w + xc + p_off];
    float est = m_at_s_lmmse(p, mfit, sfit, yc, xc, in_w, p_w, p_off, shot_m, floor_m, shot_s, floor_s);
    const int iy0 = (yc + y_off) * y_w + xc + y_off;
    const int il0 = (yc + l_off) * l_w + xc + l_off;
    float num = 0.0f, den = 0.0f, err_min = INFINITY;
    #pragma unroll
    for (int k = 0; k < 4; ++k) {
        const int dy = k == 0 ? 0 : 1, dx = k == 0 ? 1 : (k == 1 ? 0 : (k == 2 ? 1 : -1));
        const int o = dy * y_w + dx;
        float err = 0.0f, cnt_k = 0.0f;
        #pragma unroll
        for (int uy = -1; uy <= 1; ++uy) {
            #pragma unroll
            for (int ux = -1; ux <= 1; ++ux) {
                const int ui = iy0 + uy * y_w + ux;
                if (!s_rel(uy, ux) && !s_rel(uy - dy, ux - dx) && !s_rel(uy + dy, ux + dx)) {   /* compile time */
                    const float pe = 0.5f * (yg[ui - o] + yg[ui + o]) - yg[ui];
                    err += pe * pe;
                    cnt_k += 1.0f;
                }
            }
        }
        err /= cnt_k;
        const float wk = 1.0f / (err + dir_eps);
        num += wk * 0.5f * (yg[iy0 - o] + yg[iy0 + o]);
        den += wk;
        err_min = min_f(err_min, err);
    }
    float hf = 0.0f;
    #pragma unroll
    for (int dy = -COMBINE_RADIUS; dy <= COMBINE_RADIUS; ++dy) {
        #pragma unroll
        for (int dx = -COMBINE_RADIUS; dx <= COMBINE_RADIUS; ++dx) {
            const float dd = yg[iy0 + dy * y_w + dx] - ylpg[il0 + dy * l_w + dx];
            hf += dd * dd;
        }
    }
    const float e5 = hf * (1.0f / COMBINE_AREA);
    hf = kappa * e5;
    const float total = hf + err_min;
    const float w = total > 0.0f ? hf / total : 0.0f;
    est = w * (num / den - cg[iy0]) + (1.0f - w) * est;
    const float e_sig = max_f(e5 - blend_k * (lum_shot * max_f(ylpg[il0], 0.0f) + lum_floor), 0.0f);
    const float mn = m_from_s * pc;
    const float dev = est - mn;
    est = mn + alias_gain(dev * dev, alias_m * e_sig) * dev;
    dst[y * out_w + x] = est;
}

/* lum_lowpass: ylp = D * m (D: centre 1/2 plus the off-centre taps, D_SUM; d is unread). R = 4. */
__kernel void lum_lowpass(__global const float *restrict m, __global float *restrict dst, const int in_w, const int out_w,
                          const int oy, const int ox, __constant const float *restrict d, const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    __global const float *c = m + (y + D_RADIUS) * in_w + (x + D_RADIUS);
    const float acc = d_offcentre(c, in_w);
    /* two bitwise-equal forms (scaling by 2 is exact) selected by the lattice: PoCL then vectorises
     * 8 wide, not 4 (measured 3x faster; a lone acc + c / 2 gets 4) */
    dst[y * out_w + x] = at_l(y + D_RADIUS + oy, x + D_RADIUS + ox) ? acc + 0.5f * c[0] : (2.0f * acc + c[0]) * 0.5f;
}

/* chroma_input: cin = B5 * ((m - ylp) mod), mod = +1 at L sites, -1 elsewhere (the (pi, pi) carrier);
 * ylp on the kernel's window (width in_w), m on a window larger by 4 (width m_w). b5: the 5 x 5
 * weights, row order (unread: B5_SUM has them as literals). The carrier is +-1 with the
 * checkerboard's sign, so it is taken out of the sum (mod(centre) (-1)^(dy + dx) at each tap, exact):
 * no lattice test per tap. R = 2. */
__kernel void chroma_input(__global const float *restrict m, __global const float *restrict ylp, __global float *restrict dst,
                           const int in_w, const int m_w, const int out_w, const int oy, const int ox,
                           __constant const float *restrict b5, const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    __global const float *mc = m + (y + D_RADIUS + PRE_RADIUS) * m_w + x + D_RADIUS + PRE_RADIUS;
    __global const float *lc = ylp + (y + PRE_RADIUS) * in_w + x + PRE_RADIUS;
#define P(dy, dx) (mc[(dy) * m_w + (dx)] - lc[(dy) * in_w + (dx)])
    const float acc = B5_SUM(P);
#undef P
    dst[y * out_w + x] = acc * mod_f(y + PRE_RADIUS + oy, x + PRE_RADIUS + ox);
}

/* chroma_guide: dst = ylp + lambda cin on cin's window (ylp's larger by PRE = 2): the chroma
 * filter's colour-aware guide (LMSGuidedParams.chroma_guide). R = 0. */
__kernel void chroma_guide(__global const float *restrict ylp, __global const float *restrict cin,
                           __global float *restrict dst, const int ylp_w, const int out_w, const float lambda,
                           const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    dst[y * out_w + x] = ylp[(y + PRE_RADIUS) * ylp_w + x + PRE_RADIUS] + lambda * cin[y * out_w + x];
}

/* keep_luminance: y = m - c mod (every sample kept: L - c at L sites, M + c elsewhere); c on the
 * kernel's window, m on a window larger by m_off. R = 0. */
__kernel void keep_luminance(__global const float *restrict m, __global const float *restrict c, __global float *restrict dst,
                             const int m_w, const int m_off, const int out_w, const int oy, const int ox,
                             const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    dst[y * out_w + x] = m[(y + m_off) * m_w + x + m_off] - c[y * out_w + x] * mod_f(y + oy, x + ox);
}

/* lm_energy: the four per-pixel energies whose 5 x 5 means lm_output needs (planes 0..3): d^2 with
 * d = y - ylp = m - c mod - ylp (luminance detail beyond the quincunx baseband); dev^2 with
 * dev = c - chroma_neutral ylp (the chroma's deviation from grey); bp^2 with bp = the 9 x 9 half-Nyquist
 * diagonal band-pass of ylp (bp_w: its 1-D weights at offsets -4, -2, 0, 2, 4; response sin^4 wx
 * sin^4 wy); ac^2 with ac = ylp - its 5 x 5 mean. c on the kernel's window (width out_w), m and ylp on
 * windows larger by m_off and l_off (l_off >= 4). R = 0 here; reads ylp +-4. */
__kernel void lm_energy(__global const float *restrict m, __global const float *restrict c, __global const float *restrict ylp,
                        __global float *restrict dst, const int m_w, const int m_off, const int l_w, const int l_off,
                        const int out_w, const int out_h, const int oy, const int ox,
                        const float chroma_neutral, __constant const float *restrict bp_w)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int i = y * out_w + x;
    __global const float *lc = ylp + (y + l_off) * l_w + x + l_off;
    const float lk = lc[0];
    const float d = m[(y + m_off) * m_w + x + m_off] - c[i] * mod_f(y + oy, x + ox) - lk;
    const float dev = c[i] - chroma_neutral * lk;
    float bp = 0.0f, mean = 0.0f;
    #pragma unroll
    for (int u = -COMBINE_RADIUS; u <= COMBINE_RADIUS; ++u) {        /* band-pass taps at 2u: BP_RADIUS */
        #pragma unroll
        for (int v = -COMBINE_RADIUS; v <= COMBINE_RADIUS; ++v) {
            bp += bp_w[u + COMBINE_RADIUS] * bp_w[v + COMBINE_RADIUS] * lc[2 * u * l_w + 2 * v];
            mean += lc[u * l_w + v];
        }
    }
    const float ac = lk - mean * (1.0f / COMBINE_AREA);
    const int plane = out_w * out_h;
    dst[i] = d * d;
    dst[plane + i] = dev * dev;
    dst[2 * plane + i] = bp * bp;
    dst[3 * plane + i] = ac * ac;
}

/* lm_output: L, M, E_sig (planes 0, 1, 2): y = m - c mod, d = y - ylp, E = 5 x 5 mean of d^2,
 * E_sig = max(E - blend_k vn, 0), vn = lum_shot max(ylp, 0) + lum_floor (the noise of d; 0 noiseless);
 * noiseless Y = ylp + d (= y); noisy Y = ybl + w (y - ybl), ybl = m / 2 + (sum of m's 4 axial
 * neighbours) / 8 (the flat-field target: zero at the (pi, pi) chroma carrier, noise gain 0.3125),
 * w = E_sig / E. Alias suppression of the chroma toward the neutral cn ylp: dev = c - cn ylp,
 * c' = cn ylp + alias_gain(5 x 5 mean of dev^2, alias_c E_sig + alias_h tonal(E_h, E_ac)) dev
 * (E_h, E_ac: 5 x 5 means of bp^2, ac^2); L = Y + c', M = Y - c'. rows: the row sums over x .. x + 4 of lm_energy's four planes
 * (box_rows, r = 2; rows_w x rows_h each), summed here over y .. y + 4. c on the kernel's window
 * (width in_w), m and ylp on windows larger by m_off, l_off. R = 2. */
__kernel void lm_output(__global const float *restrict m, __global const float *restrict c, __global const float *restrict ylp,
                        __global const float *restrict rows, __global float *restrict dst, const int in_w, const int m_w,
                        const int m_off, const int l_w, const int l_off, const int rows_w, const int rows_h,
                        const int out_w, const int out_h, const int oy, const int ox, const float blend_k,
                        const float lum_shot, const float lum_floor, const float chroma_neutral,
                        const float alias_c, const float alias_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int yc = y + COMBINE_RADIUS, xc = x + COMBINE_RADIUS, ic = yc * in_w + xc;
    const int il = (yc + l_off) * l_w + xc + l_off;
    const int im = (yc + m_off) * m_w + xc + m_off;
    const int rplane = rows_w * rows_h;
    float e = 0.0f, c2 = 0.0f, e_h = 0.0f, e_ac = 0.0f;
    #pragma unroll
    for (int j = 0; j < COMBINE_SIDE; ++j) {
        const int k = (y + j) * rows_w + x;
        e += rows[k];
        c2 += rows[rplane + k];
        e_h += rows[2 * rplane + k];
        e_ac += rows[3 * rplane + k];
    }
    e *= 1.0f / COMBINE_AREA;
    c2 *= 1.0f / COMBINE_AREA;
    e_h *= 1.0f / COMBINE_AREA;
    e_ac *= 1.0f / COMBINE_AREA;
    const float tone = tonal(e_h, e_ac);
    const float lc = ylp[il];
    const float e_sig = max_f(e - blend_k * (lum_shot * max_f(lc, 0.0f) + lum_floor), 0.0f);
    const float yv = m[im] - c[ic] * mod_f(yc + oy, xc + ox);
#if NOISY
    const float w = e > 0.0f ? e_sig / e : 0.0f;
    const float ybl = 0.5f * m[im] + 0.125f * (m[im - m_w] + m[im + m_w] + m[im - 1] + m[im + 1]);
    const float lum = ybl + w * (yv - ybl);
#else
    const float lum = lc + (yv - lc);
#endif
    const float cn = chroma_neutral * lc;
    const float c_out = cn + alias_gain(c2, alias_c * e_sig + alias_h * tone) * (c[ic] - cn);
    const int i = y * out_w + x, plane = out_w * out_h;
    dst[i] = lum + c_out;
    dst[plane + i] = lum - c_out;
    dst[2 * plane + i] = e_sig;
}

/* s_residual: rs = p - g at the S sites, 0 elsewhere (the residual s_output interpolates), on g's
 * window (width in_w; p on a window larger by p_off). One lattice test per pixel instead of one per
 * tap in s_output. R = 0. */
__kernel void s_residual(__global const float *restrict p, __global const float *restrict g, __global float *restrict dst, const int in_w,
                         const int p_w, const int p_off, const int oy, const int ox, const int out_h)
{
    const int x = inward_id(0, in_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int i = y * in_w + x;
    dst[i] = at_s(y + oy, x + ox) ? p[(y + p_off) * p_w + x + p_off] - g[i] : 0.0f;
}

/* s_output: the three planes L, M, S before s_alias: L, M copied from lm (a window larger by lm_off on
 * every side of the output, 2 planes of lm_w x lm_h) and S = g + gamma_S * (tent interpolation over the
 * S sites of the 7 x 7 of the residuals rs = p - g, s_residual's plane), gamma_S = 1 (noiseless) or
 * max(E - var_S(g), 0) / E, E = mean over those S sites of rs^2. g and rs on the kernel's window (width
 * in_w). tent: the TENT_TAPS weights. lat: the lattice-only sums, 2 x 4 rows of in_w (host-made,
 * s_output_lattice): row (image row & 3) the tent's weight over the S sites (the denominator), row
 * 4 + (image row & 3) the count of S sites in the 7 x 7. R = 3. */
__kernel void s_output(__global const float *restrict rs, __global const float *restrict g, __global const float *restrict lm,
                       __global float *restrict dst, __global const float *restrict lat, const int in_w, const int lm_w,
                       const int lm_h, const int lm_off, const int out_w, const int out_h, const int oy,
                       __constant const float *restrict tent, const float shot_s, const float floor_s)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int yc = y + RI_RADIUS, xc = x + RI_RADIUS;
    __global const float *rc = rs + yc * in_w + xc;
    __global const float *lr = lat + ((yc + oy) & 3) * in_w + xc;
    float num = 0.0f;
#define X(dy, dx, t) num += tent[t] * rc[(dy) * in_w + (dx)];
    TENT_TAPS
#undef X
    const float den = lr[0];
    const float g0 = g[yc * in_w + xc];
#if NOISY
    float e = 0.0f;
    #pragma unroll
    for (int dy = -RI_RADIUS; dy <= RI_RADIUS; ++dy) {
        #pragma unroll
        for (int dx = -RI_RADIUS; dx <= RI_RADIUS; ++dx) {
            const float res = rc[dy * in_w + dx];
            e += res * res;
        }
    }
    e /= lr[4 * in_w];
    const float gamma = e > 0.0f ? max_f(e - (shot_s * max_f(g0, 0.0f) + floor_s), 0.0f) / e : 0.0f;
#else
    const float gamma = 1.0f;
#endif
    const int i = y * out_w + x, plane = out_w * out_h;
    const int li = (y + lm_off) * lm_w + x + lm_off;
    dst[i] = lm[li];
    dst[plane + i] = lm[lm_w * lm_h + li];
    dst[2 * plane + i] = g0 + gamma * num / den;
}

/* s_tone_energy: the two per-pixel energies of the axial tonal alias detector (planes 0, 1), on the
 * window of lms shrunk by 2: hx^2 + hy^2 with hx = hp * Y, hy = hp^T * Y (hp: the 3 x 3 AXIAL_HP weights,
 * row order; high-pass across x, low-pass along y), and ac^2 with ac = Y - its 5 x 5 mean; Y = (L + M) / 2
 * from planes 0, 1 of lms (in_w x in_h). Reads +-2. */
__kernel void s_tone_energy(__global const float *restrict lms, __global float *restrict dst, const int in_w, const int in_h,
                            const int out_w, const int out_h, __constant const float *restrict hp)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int plane = in_w * in_h, ic = (y + COMBINE_RADIUS) * in_w + x + COMBINE_RADIUS;
    float hx = 0.0f, hy = 0.0f, mean = 0.0f;
    #pragma unroll
    for (int dy = -COMBINE_RADIUS; dy <= COMBINE_RADIUS; ++dy) {
        #pragma unroll
        for (int dx = -COMBINE_RADIUS; dx <= COMBINE_RADIUS; ++dx) {
            const int k = ic + dy * in_w + dx;
            const float lum = 0.5f * (lms[k] + lms[plane + k]);
            mean += lum;
            if (dy >= -HP_RADIUS && dy <= HP_RADIUS && dx >= -HP_RADIUS && dx <= HP_RADIUS) {   /* compile time */
                hx += hp[(dy + HP_RADIUS) * (2 * HP_RADIUS + 1) + dx + HP_RADIUS] * lum;
                hy += hp[(dx + HP_RADIUS) * (2 * HP_RADIUS + 1) + dy + HP_RADIUS] * lum;
            }
        }
    }
    const float ac = 0.5f * (lms[ic] + lms[plane + ic]) - mean * (1.0f / COMBINE_AREA);
    const int i = y * out_w + x;
    dst[i] = hx * hx + hy * hy;
    dst[out_w * out_h + i] = ac * ac;
}

/* s_alias: the three output planes: L, M copied, S' = s_from_m M + alias_gain(5 x 5 mean of sd^2,
 * alias_s E_sig + alias_st tonal(E_ax, E_ac)) sd, sd = S - s_from_m M (alias suppression toward the
 * neutral); E_ax and E_ac the 5 x 5 means of s_tone_energy's planes (rows: their row sums over x .. x + 4, rows_w x rows_h
 * each, summed here over y .. y + 4). lms: 3 planes on the kernel's window (in_w x in_h); E_sig: plane 2
 * of lm (lm_w x lm_h) on a window larger by lm_off. R = 4. */
__kernel void s_alias(__global const float *restrict lms, __global const float *restrict lm, __global const float *restrict rows,
                      __global float *restrict dst, const int in_w, const int in_h, const int lm_w, const int lm_h,
                      const int lm_off, const int rows_w, const int rows_h, const int out_w, const int out_h,
                      const float s_from_m, const float alias_s, const float alias_st)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int plane = in_w * in_h, ic = (y + S_ALIAS_RADIUS) * in_w + x + S_ALIAS_RADIUS;
    float s2 = 0.0f;
    #pragma unroll
    for (int dy = -COMBINE_RADIUS; dy <= COMBINE_RADIUS; ++dy) {
        #pragma unroll
        for (int dx = -COMBINE_RADIUS; dx <= COMBINE_RADIUS; ++dx) {
            const int k = ic + dy * in_w + dx;
            const float sd = lms[2 * plane + k] - s_from_m * lms[plane + k];
            s2 += sd * sd;
        }
    }
    s2 *= 1.0f / COMBINE_AREA;
    float e_ax = 0.0f, e_ac = 0.0f;
    #pragma unroll
    for (int j = 0; j < COMBINE_SIDE; ++j) {
        e_ax += rows[(y + j) * rows_w + x];
        e_ac += rows[rows_w * rows_h + (y + j) * rows_w + x];
    }
    e_ax *= 1.0f / COMBINE_AREA;
    e_ac *= 1.0f / COMBINE_AREA;
    const float e_sig = lm[2 * lm_w * lm_h + (y + S_ALIAS_RADIUS + lm_off) * lm_w + x + S_ALIAS_RADIUS + lm_off];
    const float alias = alias_s * e_sig + alias_st * tonal(e_ax, e_ac);
    const float mn = s_from_m * lms[plane + ic];
    const int i = y * out_w + x, out_plane = out_w * out_h;
    dst[i] = lms[ic];
    dst[out_plane + i] = lms[plane + ic];
    dst[2 * out_plane + i] = mn + alias_gain(s2, alias) * (lms[2 * plane + ic] - mn);
}
