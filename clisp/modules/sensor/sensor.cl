/* Sensor corrections (clisp/modules/sensor/stage.py: the definition of correct, its reference).
 *
 * Defines from the host (no defaults here):
 *   RAW_T         the mosaic's sample type (ushort, float)
 *   CFA_PERIOD    side of the CFA's repeating tile
 *   SC_HALO       3: the window's margin (the same-channel neighbours within SC_RADIUS, and the
 *                 4 nearest pixels of each, which the replacement's Y reads)
 *   SC_RADIUS     2: the same-channel neighbourhood's radius
 *   SC_NB_MAX     most same-channel neighbours of a phase within SC_RADIUS (table stride)
 *   SC_PAIRS_MAX  most opposite neighbour pairs of a phase (table stride)
 *   SC_DETECT     1: search defective pixels against the noise model (the auto test)
 *   SC_MASK       1: a plane of known bad pixels (a map file, the DNG's FixBadPixels opcodes)
 *   SC_DARK       1: a per-pixel dark level (DN) replaces the black level
 *   SC_FLAT       1: a per-pixel flat-field gain
 *   SC_TERMS      number of opcode gain terms (GainMap, FixVignetteRadial of OpcodeLists 1, 2)
 *   SC_GRID       1: divide by the smooth gain G (applied after the chroma stage by sensor_shade)
 *   SC_K, SC_K_COLD, SC_HOT_SLOPE, SC_HOT_CAP, SC_ALPHA, SC_GAMMA, SC_Z, SC_RHO, SC_KR, SC_FLOOR   the auto test's
 *   constants (float literals)
 *   SC_TERM_SIZE  floats per packed gain term
 *   SC_EDGE_RUN   pixels of a row each work-item of sensor_list's edge part (edges_run) appends
 */

#include "sensor.h"
#include "mirror.h"

/* The window's geometry and the per-pixel steps shared by both kernels. src is the window,
 * (width + 2 SC_HALO) x (height + 2 SC_HALO), i.e. (width + 6) x (height + 6); (x, y) an output
 * pixel; the image pixel is (y + SC_HALO + oy, x + SC_HALO + ox). */
#define W_AT(q) ((float)src[q] * g1 - OFF(q))
/* OpcodeList 1's gain at image pixel (gy, gx): the product of its terms, 1 without any. */
#if SC_TERMS
#define GAIN1(gy, gx) list_gain(terms, maps, 1, gy, gx)
#else
#define GAIN1(gy, gx) 1.0f
#endif
#if SC_DARK
#define OFF(q) dark[q]
#else
#define OFF(q) black[c]
#endif
#define SC_ARGS __global const RAW_T *restrict src, __global float *restrict dst, \
        const int width, const int height, const int oy, const int ox, \
        __constant const char *restrict pattern, \
        __constant const float *restrict black, __constant const float *restrict inv_range, \
        __constant const float *restrict out_scale, __constant const float *restrict out_offset, \
        __constant const float *restrict noise_a, __constant const float *restrict noise_b, \
        __global const ushort *restrict mask, __global const float *restrict dark, \
        __global const float *restrict flat, \
        __constant const float *restrict terms, __global const float *restrict maps, \
        __global const float *restrict grid, const int gh, const int gw, const float inv_cell, \
        const int img_h, const int img_w

/* gain_after: r(p) = flat(p) g2(p) / G_c(p), the gains after the bad-pixel step (step 3). */
inline float gain_after(__global const float *flat, __constant const float *terms, __global const float *maps,
                        __global const float *grid, const int gh, const int gw, const float inv_cell,
                        const int i, const int c, const int gy, const int gx)
{
    float r = 1.0f;
#if SC_FLAT
    r *= flat[i];
#endif
#if SC_TERMS
    r *= list_gain(terms, maps, 2, gy, gx);
#endif
#if SC_GRID
    r /= grid_gain(grid, gh, gw, inv_cell, c, (float)gy, (float)gx);
#endif
    return r;
}

/* sensor_screen: 8 pixels of a row per work-item, over the window less the halo (2): the steps
 * without the bad-pixel replacement, out = (raw g1 - off) r out_scale_c + out_offset_c (off: the dark
 * frame or the black level; r: gain_after), and the candidates for sensor_fix flagged in ``flags``
 * (a byte per 8 pixels, listed by sensor_list; the scalar path appends them to ``list`` itself,
 * ``count`` of them, at most ``cap`` kept): known bad pixels (mask) and (SC_DETECT) pixels beyond
 * their same-channel neighbours at (+-2, +-2) (the same channel in the Bayer and LMS CFAs; SC_DIAG 0:
 * every pixel) and, in a 2 x 2 CFA, at (0, +-2) and (+-2, 0) (the vector path) by SC_K sigmas
 * (a hot one: at their highest level; a dead one, SC_K_COLD: at their lowest where the lane table allows it,
 * stage.cold_at_level, else at 0) plus SC_FLOOR plus SC_ALPHA times their range, SC_SLACK looser:
 * sensor_fix's test restricted to a subset of its neighbours (and without the hot side's level-following
 * margin, SC_HOT_SLOPE, which only asks more), so a pixel it would replace is never
 * left out; and (SC_MASK and SC_DETECT) pixels with a known bad neighbour among those, which
 * sensor_fix leaves out of its test. The pixels within 2 of the image's edge, whose neighbours the
 * padding mirrors, are appended by sensor_list (edges_run) instead. The 8 lanes are explicit float8 (PoCL's implicit
 * vectoriser gives up on the atomic append: 8 against 50 ms for 6 MP); the test is branch-free
 * (squares, not sqrt); only the rare candidates branch. Bounds checked; a row's last group of fewer
 * than 8 pixels takes the scalar path. */
#define LANES 8
#define SC_CAT(a, b) a##b
#define SC_VEC(t, n) SC_CAT(t, n)
#if SC_DARK
#define SC_ROW_T float
#else
#define SC_ROW_T RAW_T
#endif
inline int screen_one(__global const RAW_T *src, __constant const char *pattern, __constant const float *black,
                      __constant const float *inv_range, __constant const float *noise_a,
                      __constant const float *noise_b, __global const ushort *mask, __global const float *dark,
                      const float g1, const int i, const int sw, const int c, const float w)
{
    int cand = 0;
#if SC_DETECT
    const float d0 = W_AT(i - 2 * sw - 2), d1 = W_AT(i - 2 * sw + 2), d2 = W_AT(i + 2 * sw - 2), d3 = W_AT(i + 2 * sw + 2);
    const float m0 = d0 > d1 ? d0 : d1, m1 = d2 > d3 ? d2 : d3, n0 = d0 < d1 ? d0 : d1, n1 = d2 < d3 ? d2 : d3;
    const float s = inv_range[c];
    const float up = w * s, uhi = (m0 > m1 ? m0 : m1) * s, ulo = (n0 < n1 ? n0 : n1) * s;
    const float spread = SC_ALPHA * (uhi - ulo) + SC_FLOOR;
    const float eh = up - uhi - spread, el = ulo - up - spread;
    const float level = uhi > 0.0f ? uhi : 0.0f;
    cand = ((eh > 0.0f) && (eh * eh > SC_K * SC_K * (noise_a[c] * level + noise_b[c])))
         || ((el > 0.0f) && (el * el > SC_K_COLD * SC_K_COLD * noise_b[c])) || !SC_DIAG;
#endif
#if SC_MASK
    cand |= mask[i] != 0;
#if SC_DETECT
    /* sensor_fix leaves known bad neighbours out of its test: a pixel with one among those above */
    cand |= (mask[i - 2 * sw - 2] | mask[i - 2 * sw + 2] | mask[i + 2 * sw - 2] | mask[i + 2 * sw + 2]) != 0;
#endif
#endif
    return cand;
}

inline void append(__global uint *list, __global uint *count, const uint cap, const uint p)
{
    const uint k = atomic_inc(count);
    if (k < cap)
        list[k] = p;
}

__kernel void sensor_screen(SC_ARGS, __global uint *restrict list, __global uint *restrict count, const uint cap,
                            __constant const float *restrict lanes8, __global uchar *restrict flags)
{
    const int xg = get_global_id(0);
    const int y = get_global_id(1);
    const int x0 = xg * LANES;
    if (x0 >= width || y >= height)
        return;
    const int sw = width + 2 * SC_HALO;
    const int gy = y + SC_HALO + oy, gx0 = x0 + SC_HALO + ox;
    const int i0 = (y + SC_HALO) * sw + x0 + SC_HALO;
    const int edge_row = gy < 2 || gy >= img_h - 2;
    if (x0 + LANES > width || SC_TERMS || SC_GRID) {          /* the scalar path */
#if SC_DETECT || SC_MASK
        flags[y * ((width + LANES - 1) / LANES) + xg] = 0;        /* its candidates appended below */
#endif
        for (int k = 0; k < LANES && x0 + k < width; k++) {
            const int i = i0 + k, gx = gx0 + k;
            const int c = cfa_channel(pattern, gy, gx);
            const float g1 = GAIN1(gy, gx);
            const float w = W_AT(i);
#if SC_DETECT || SC_MASK
            if (screen_one(src, pattern, black, inv_range, noise_a, noise_b, mask, dark, g1, i, sw, c, w)
                && !edge_row && gx >= 2 && gx < img_w - 2)
                append(list, count, cap, (uint)(y * width + x0 + k));
#endif
            dst[y * width + x0 + k] = w * gain_after(flat, terms, maps, grid, gh, gw, inv_cell, i, c, gy, gx)
                                      * out_scale[c] + out_offset[c];
        }
        return;
    }
    /* the 8 lanes' channel constants: lanes8[((py P + px) 7 + j) 8 + k], j = black, 1 / range,
     * noise a, noise b, out scale, out offset, cold level (stage.lane_constants), for lane k of a group
     * starting at phase (py, px) */
    const int py = ((gy % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD, px = ((gx0 % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD;
    __constant const float *lc = lanes8 + (py * CFA_PERIOD + px) * SC_LANE_ROWS * LANES;
    const float8 blk = vload8(0, lc), inv = vload8(1, lc), na = vload8(2, lc), nb8 = vload8(3, lc);
    const float8 osc = vload8(4, lc), oof = vload8(5, lc);
#if SC_DARK
#define OFF8(q) vload8(0, dark + (q))
#else
#define OFF8(q) blk
#endif
#define W8(q) (convert_float8(vload8(0, src + (q))) - OFF8(q))
#if SC_DETECT
    /* each of the rows -2, 0, +2 read once, 16 samples from 2 left of the group (12 used; the
     * window's halo of 3 and the row after keep the reads inside it): its columns -2, 0, +2 are the
     * lanes .s0-7, .s2-9, .s4-b. The neighbours (the pixel's own channel) compared as read (DN:
     * ushort vectors where the raw is, cheaper than float) and their highest and lowest made w
     * once; with a dark frame the offset differs per pixel, so in float. Ternaries, which PoCL
     * vectorises (select(), max() and fmax() it does not). */
#if SC_DARK
#define ROW16(q) (convert_float16(vload16(0, src + (q) - 2)) - vload16(0, dark + (q) - 2))
    typedef float8 nb_t;
#define TO_W(v) (v)
#else
#define ROW16(q) vload16(0, src + (q) - 2)
    typedef SC_VEC(RAW_T, 8) nb_t;
#define TO_W(v) (convert_float8(v) - blk)
#endif
    const SC_VEC(SC_ROW_T, 16) top = ROW16(i0 - 2 * sw), mid = ROW16(i0), bot = ROW16(i0 + 2 * sw);
    const float8 w = TO_W(mid.s23456789);
#else
    const float8 w = W8(i0);
#endif
#if SC_DETECT || SC_MASK
    int8 cand = (int8)(0);
#if SC_DETECT
    /* the same-channel neighbours at (+-2, +-2) (the same channel in the Bayer and LMS CFAs) and,
     * SC_EVEN (a 2 x 2 CFA: every even offset has the pixel's channel), at (0, +-2), (+-2, 0) */
    nb_t hi_n = top.s01234567, lo_n = hi_n;
#define NB8(e) { const nb_t v = (e); hi_n = v > hi_n ? v : hi_n; lo_n = v < lo_n ? v : lo_n; }
    NB8(top.s456789ab) NB8(bot.s01234567) NB8(bot.s456789ab)
#if SC_EVEN
    NB8(mid.s01234567) NB8(mid.s456789ab) NB8(top.s23456789) NB8(bot.s23456789)
#endif
    const float8 hi = TO_W(hi_n), lo = TO_W(lo_n);
    const float8 up = w * inv, uhi = hi * inv, ulo = lo * inv;
    const float8 spread = SC_ALPHA * (uhi - ulo) + SC_FLOOR;
    /* sensor_fix's test over fewer neighbours, in squares (no sqrt), SC_SLACK looser so that its
     * rounding never leaves out a pixel sensor_fix would take. Hot: the noise at the highest
     * neighbour's level (a higher one among the rest only makes a pixel less hot). Cold: at the lowest
     * one's level where lane_constants' row 6 is 1 (the channel's noise grows slowly enough with the
     * level that a lower neighbour among the rest only makes the pixel less cold), else at 0 */
    const float8 eh = up - uhi - spread + SC_SLACK, el = ulo - up - spread + SC_SLACK;
    const float8 level = uhi > 0.0f ? uhi : (float8)(0.0f);
    const float8 cold_level = vload8(6, lc) * (ulo > 0.0f ? ulo : (float8)(0.0f));
    const float k2 = (1.0f - SC_SLACK) * SC_K * SC_K, k2c = (1.0f - SC_SLACK) * SC_K_COLD * SC_K_COLD;
    cand = ((eh > 0.0f) & (eh * eh > k2 * (na * level + nb8)))
         | ((el > 0.0f) & (el * el > k2c * (na * cold_level + nb8)));
#endif
#if SC_MASK
    cand |= convert_int8(vload8(0, mask + i0)) != 0;
#if SC_DETECT
    {   /* sensor_fix leaves known bad neighbours out of its test (a brighter one would have hidden a hot
         * pixel here): a pixel with one among those above is a candidate */
        const ushort16 mt = vload16(0, mask + i0 - 2 * sw - 2), mb = vload16(0, mask + i0 + 2 * sw - 2);
        ushort8 near = mt.s01234567 | mt.s456789ab | mb.s01234567 | mb.s456789ab;
#if SC_EVEN
        const ushort16 mm = vload16(0, mask + i0 - 2);
        near |= mm.s01234567 | mm.s456789ab | mt.s23456789 | mb.s23456789;
#endif
        cand |= convert_int8(near) != 0;
    }
#endif
#endif
    /* the lanes' candidates as the bits of one byte, listed by sensor_list: an append here (an
     * atomic in a branch) would cost the kernel a third of its time */
    const int8 bits = cand & (int8)(1, 2, 4, 8, 16, 32, 64, 128);
    flags[y * ((width + LANES - 1) / LANES) + xg] = (uchar)(bits.s0 | bits.s1 | bits.s2 | bits.s3 | bits.s4 | bits.s5 | bits.s6 | bits.s7);
#endif
    float8 r = (float8)(1.0f);
#if SC_FLAT
    r = vload8(0, flat + i0);
#endif
    vstore8(w * r * osc + oof, 0, dst + y * width + x0);
}

/* compact_run: appends the candidates sensor_screen flagged (bit k of flags[y groups + g]: output
 * pixel (y, 8 g + k)) to ``list``, but those within 2 of the image's edge (edges_run lists them).
 * Halo 0; one work-item (gx, y) per 64 groups of a row (``groups`` of them), bounds checked. */
inline void compact_run(const int gx, const int y, __global const uchar *restrict flags, __global uint *restrict list,
                        __global uint *restrict count, const uint cap, const int width, const int height,
                        const int groups, const int oy, const int ox, const int img_h, const int img_w)
{
    const int g0 = gx * 64;
    if (g0 >= groups || y >= height)
        return;
    const int gy = y + SC_HALO + oy;
    if (gy < 2 || gy >= img_h - 2)
        return;
    __global const uchar *f = flags + y * groups;
    const int g1 = min(g0 + 64, groups);
    /* the pixels 2 or more inside the image's left and right edges: output columns [xlo, xhi) */
    const int xlo = 2 - SC_HALO - ox, xhi = img_w - 2 - SC_HALO - ox;
    /* counted first, then one atomic for the work-item's run (an atomic per candidate made this
     * kernel cost a third of the screen at 2 % candidates) */
    uint n = 0;
    for (int g = g0; g < g1; g++) {
        uint m = f[g];
        if (g * LANES < xlo || g * LANES + LANES > xhi)
            for (int k = 0; k < LANES; k++)
                if (g * LANES + k < xlo || g * LANES + k >= xhi)
                    m &= ~(1u << k);
        n += popcount(m);
    }
    if (!n)
        return;
    uint at = atomic_add(count, n);
    for (int g = g0; g < g1; g++) {
        uint m = f[g];
        while (m) {
            const int k = 31 - clz(m & -m);              /* the lowest bit set */
            m &= m - 1;
            const int x = g * LANES + k;
            if (x >= xlo && x < xhi) {
                if (at < cap)
                    list[at] = (uint)(y * width + x);
                at++;
            }
        }
    }
}

/* The rectangle of a launch over stacked rectangles (stage.stacked): ``strips`` holds n of them as
 * (y0, x0, rows, cols, first), their rows stacked along the launch's y from row ``first``. Row g of
 * the launch is row *y of rectangle k (the return value); *y >= its rows past the last one. */
inline int stacked_strip(__constant const int *strips, const int n, const int g, int *y)
{
    int k = 0;
    for (int s = 1; s < n; s++)
        k += g >= strips[5 * s + 4];
    *y = g - strips[5 * k + 4];
    return k;
}

/* edges_run: appends every output pixel of the rectangles (stage.edge_strips, stacked:
 * stacked_strip) to ``list`` (the window's pixels inside the image within 2 of its edge:
 * sensor_fix tests them with the neighbours inside the image only; pixels beyond the image are not
 * tested, sensor_mirror pads them). Halo 0; one work-item (gx, g) per SC_EDGE_RUN pixels of a
 * stacked row g, one atomic for them (an atomic per pixel cost as much as the screen), bounds
 * checked; one launch for every rectangle (a launch per rectangle cost PoCL's dispatch four times). */
inline void edges_run(const int gx, const int g, __global uint *restrict list, __global uint *restrict count,
                      const uint cap, const int width, __constant const int *restrict strips, const int n_strips)
{
    int y;
    const int r = stacked_strip(strips, n_strips, g, &y);
    const int xs = gx * SC_EDGE_RUN, cols = strips[5 * r + 3];
    if (xs >= cols || y >= strips[5 * r + 2])
        return;
    const int m = min(SC_EDGE_RUN, cols - xs);
    const uint k = atomic_add(count, (uint)m);
    const uint p = (uint)((strips[5 * r] + y) * width + strips[5 * r + 1] + xs);
    for (int j = 0; j < m; j++)
        if (k + j < cap)
            list[k + j] = p + j;
}

/* sensor_list: the candidates' list, from the screen's flags (compact_run, work-groups 0 along the
 * third index) and, in a launch 2 deep, the window's pixels near the image's edge (edges_run, 1):
 * both only append, in any order (sensor_fix's result does not depend on it), so one command does
 * both. Halo 0. */
__kernel void sensor_list(__global const uchar *restrict flags, __global uint *restrict list,
                          __global uint *restrict count, const uint cap, const int width, const int height,
                          const int groups, const int oy, const int ox, const int img_h, const int img_w,
                          __constant const int *restrict strips, const int n_strips)
{
    if (get_group_id(2) == 0)
        compact_run(get_global_id(0), get_global_id(1), flags, list, count, cap, width, height, groups, oy, ox,
                    img_h, img_w);
    else
        edges_run(get_global_id(0), get_global_id(1), list, count, cap, width, strips, n_strips);
}

/* y_near: Y at window index q (image pixel (gy, gx)): the mean of its 4 nearest pixels, each
 * (raw g1 - off) / (white - black) times its channel's white balance. */
inline float y_near(__global const RAW_T *src, __constant const char *pattern, __constant const float *black,
                    __constant const float *inv_range, __constant const float *wb, __global const float *dark,
                    const float g1, const int q, const int sw, const int gy, const int gx)
{
    float total = 0.0f;
    for (int e = 0; e < 4; e++) {
        const int dy = e == 0 ? -1 : e == 1 ? 1 : 0, dx = e == 2 ? -1 : e == 3 ? 1 : 0;
        const int cq = cfa_channel(pattern, gy + dy, gx + dx);
        const int qq = q + dy * sw + dx;
#if SC_DARK
        total += ((float)src[qq] * g1 - dark[qq]) * inv_range[cq] * wb[cq];
#else
        total += ((float)src[qq] * g1 - black[cq]) * inv_range[cq] * wb[cq];
#endif
    }
    return 0.25f * total;
}

/* sensor_fix: the candidates of sensor_screen, one work-item each (halo 3):
 *   the replacement: along the opposite same-channel pair (within 2 pixels, inside the image, not
 *   known bad) that differs least in the channel and in Y (y_near), the pair's mean plus the colour
 *   difference Y(p) - Y(pair) (the channel follows the other channels' detail, as a demosaic
 *   assumes); without a pair, the good neighbours' mean.
 *   bad pixel: known (mask), or found (SC_DETECT) where u_p, the normalised w = raw g1 - off, lies
 *   beyond every same-channel neighbour by SC_K (hot) or SC_K_COLD (dead) noise sigmas (the sensor model at that neighbour's
 *   level; a hot one by SC_HOT_SLOPE times that level, at most SC_HOT_CAP, where that is more) plus SC_FLOOR plus
 *   SC_ALPHA times their range, and then: a hot one where its 4 nearest
 *   pixels carry less than SC_GAMMA of its excess over the pair (Y(p) - Y(pair) against the excess:
 *   an optical detail lights its neighbours through the lens, a hot pixel does not; without a pair,
 *   beside the image's edge, the good neighbours' mean w and Y), a dead one where it also reads
 *   below SC_RHO times the lowest neighbour by SC_KR sigmas and reads black (below SC_K_COLD floor
 *   sigmas plus SC_FLOOR); its output is then rewritten.
 * Tables per CFA phase k = py CFA_PERIOD + px: nb_n[k] neighbours at nb[k][i] = (dy, dx), pairs_n[k]
 * opposite pairs pairs[k][j] = (i, i') (indices into nb[k]). */
__kernel void sensor_fix(SC_ARGS, __global const uint *restrict list, __global const uint *restrict count,
                         const uint cap, __constant const char *restrict nb, __constant const char *restrict nb_n,
                         __constant const char *restrict pairs, __constant const char *restrict pairs_n,
                         __constant const float *restrict wb, __global uint *restrict found)
{
    /* the list, row by row; a work-item takes every stride-th entry, so a list longer than the launch
     * (a mosaic of noise, where most pixels pass the screen) is still fixed whole */
    const uint total = min(*count, cap), stride = get_global_size(0) * get_global_size(1);
    for (uint j0 = get_global_id(1) * get_global_size(0) + get_global_id(0); j0 < total; j0 += stride) {
        const int p = (int)list[j0];
        const int y = p / width, x = p - y * width;
        const int sw = width + 2 * SC_HALO;
        const int gy = y + SC_HALO + oy, gx = x + SC_HALO + ox;
        const int py = ((gy % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD, px = ((gx % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD;
        const int k = py * CFA_PERIOD + px;
        const int c = pattern[k];
        const int i = (y + SC_HALO) * sw + x + SC_HALO;
        const float g1 = GAIN1(gy, gx);
        const float w = W_AT(i);
#if SC_MASK
        int bad = mask[i] != 0;
#else
        int bad = 0;
#endif
        const int n = nb_n[k];
        __constant const char *o = nb + 2 * k * SC_NB_MAX;
#define OUTSIDE(j) (gy + o[2 * (j)] < 0 || gy + o[2 * (j)] >= img_h || gx + o[2 * (j) + 1] < 0 || gx + o[2 * (j) + 1] >= img_w)
#if SC_MASK
#define SKIP(q, j) (OUTSIDE(j) || mask[q])
#else
#define SKIP(q, j) OUTSIDE(j)
#endif
        const float wbc = wb[c], s = inv_range[c];
#if SC_DETECT
        int extreme = 0;
        if (!bad) {                      /* first the cheap test over every same-channel neighbour */
            float hi = -INFINITY, lo = INFINITY;
            int used = 0;
            for (int j = 0; j < n; j++) {
                const int q = i + o[2 * j] * sw + o[2 * j + 1];
                if (SKIP(q, j))
                    continue;
                const float wq = W_AT(q);
                hi = fmax(hi, wq);
                lo = fmin(lo, wq);
                used++;
            }
            const float up = w * s, uhi = hi * s, ulo = lo * s;
            const float spread = SC_ALPHA * (uhi - ulo) + SC_FLOOR;
            const float hot = up - uhi - fmax(SC_K * sqrt(noise_a[c] * fmax(uhi, 0.0f) + noise_b[c]),
                                              fmin(SC_HOT_CAP, SC_HOT_SLOPE * fmax(uhi, 0.0f))) - spread;
            /* a dead pixel also reads below SC_RHO times its lowest neighbour by SC_KR sigmas of the
             * difference: a live one darker than all of them stays near them (the lens) */
            const float lo_p = fmax(ulo, 0.0f);
            const float dim = SC_RHO * lo_p - up - SC_KR * sqrt(noise_a[c] * (SC_RHO + SC_RHO * SC_RHO) * lo_p
                                                                + (1.0f + SC_RHO * SC_RHO) * noise_b[c]);
            const float cold = fmin(ulo - up - SC_K_COLD * sqrt(noise_a[c] * lo_p + noise_b[c]), dim) - spread;
            /* and it reads black (no photo-response): within SC_K_COLD floor sigmas plus SC_FLOOR */
            const int black = up < SC_K_COLD * sqrt(noise_b[c]) + SC_FLOOR;
            extreme = used && (hot > 0.0f || (cold > 0.0f && black));
            if (!extreme)
                continue;
        }
#endif
        const float yp = y_near(src, pattern, black, inv_range, wb, dark, g1, i, sw, gy, gx);
        float best = INFINITY, est = 0.0f, ybar = 0.0f, wbar = 0.0f;
        __constant const char *pr = pairs + 2 * k * SC_PAIRS_MAX;
        for (int j = 0; j < pairs_n[k]; j++) {
            const int a = pr[2 * j], b = pr[2 * j + 1];
            const int qa = i + o[2 * a] * sw + o[2 * a + 1], qb = i + o[2 * b] * sw + o[2 * b + 1];
            if (SKIP(qa, a) || SKIP(qb, b))
                continue;
            const float wa = W_AT(qa), wb_ = W_AT(qb);
            const float ya = y_near(src, pattern, black, inv_range, wb, dark, g1, qa, sw, gy + o[2 * a], gx + o[2 * a + 1]);
            const float yb = y_near(src, pattern, black, inv_range, wb, dark, g1, qb, sw, gy + o[2 * b], gx + o[2 * b + 1]);
            const float d = fabs(wa - wb_) * s + fabs(ya - yb) / wbc;
            if (d < best) {
                best = d;
                ybar = 0.5f * (ya + yb);
                wbar = 0.5f * (wa + wb_);
                est = wbar + (yp - ybar) / (wbc * s);
            }
        }
        if (best == INFINITY) {          /* no pair: the good neighbours' means stand for it */
            float sum = 0.0f, ysum = 0.0f;
            int good = 0;
            for (int j = 0; j < n; j++) {
                const int q = i + o[2 * j] * sw + o[2 * j + 1];
                if (SKIP(q, j))
                    continue;
                sum += W_AT(q);
                ysum += y_near(src, pattern, black, inv_range, wb, dark, g1, q, sw, gy + o[2 * j], gx + o[2 * j + 1]);
                good++;
            }
            est = good ? sum / (float)good : w;
            wbar = good ? est : 0.0f;
            ybar = good ? ysum / (float)good : NAN;
        }
#if SC_DETECT
        if (!bad && extreme) {
            /* the support test: how much of the excess over the pair the 4 nearest pixels carry */
            const float excess = (w - wbar) * s * wbc;
            /* the noise of Y(p) - Y(pair) (4 and 8 samples of about the pixel's channel): the support
             * must lie below SC_GAMMA by SC_Z of its sigmas, so noise alone does not make a lit detail
             * look unsupported */
            const float var = wbc * noise_a[c] * fmax(ybar, 0.0f) + wbc * wbc * noise_b[c];
            bad = fabs(excess) > 0.0f && (isnan(ybar) || (excess < 0.0f && best != INFINITY)  /* dead, surrounded: no support test */
                                          || (yp - ybar) * (excess > 0.0f ? 1.0f : -1.0f) + SC_Z * sqrt(0.375f * var)
                                             < SC_GAMMA * fabs(excess));
            if (bad)                       /* the list holds the image's pixels only (sensor_mirror pads) */
                atomic_inc(found);
        }
#endif
        if (!bad)
            continue;
        dst[p] = est * gain_after(flat, terms, maps, grid, gh, gw, inv_cell, i, c, gy, gx) * out_scale[c] + out_offset[c];
#undef OUTSIDE
#undef SKIP
    }
}

/* sensor_mirror: the window's output pixels beyond the image, the rectangles of stage.beyond_strips
 * of one width (stacked: stacked_strip), take the output at their CFA-mirror source (cfa_mirror, as the tile
 * windows are padded): the corrected image padded, which is what a later stage's halo reads of a
 * whole corrected image. A mirrored copy is never tested itself: with half its neighbours missing
 * it was taken for a defect across any edge near the image's border. A source outside the window
 * (a window less than a CFA period deep inside the image) leaves the pixel as it is. Halo 0; the
 * sources are inside the image, which no work-item writes. */
__kernel void sensor_mirror(__global float *restrict dst, const int width, const int height, const int oy,
                            const int ox, const int img_h, const int img_w, __constant const int *restrict strips,
                            const int n_strips)
{
    int y;
    const int r = stacked_strip(strips, n_strips, get_global_id(1), &y);
    const int x = get_global_id(0);
    if (x >= strips[5 * r + 3] || y >= strips[5 * r + 2])
        return;
    const int yo = strips[5 * r] + y, xo = strips[5 * r + 1] + x;
    const int sy = cfa_mirror(yo + SC_HALO + oy, img_h, CFA_PERIOD) - SC_HALO - oy;
    const int sx = cfa_mirror(xo + SC_HALO + ox, img_w, CFA_PERIOD) - SC_HALO - ox;
    if (sy >= 0 && sy < height && sx >= 0 && sx < width)
        dst[yo * width + xo] = dst[sy * width + sx];
}
