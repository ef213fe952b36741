/* Sensor corrections (clisp/modules/sensor/stage.py: the definition of correct, its reference).
 *
 * Defines from the host (no defaults here):
 *   RAW_T         the mosaic's sample type (ushort, float)
 *   CFA_PERIOD    side of the CFA's repeating tile
 *   SC_HALO       2: the same-channel neighbourhood's radius
 *   SC_NB_MAX     most same-channel neighbours of a phase within SC_HALO (table stride)
 *   SC_PAIRS_MAX  most opposite neighbour pairs of a phase (table stride)
 *   SC_DETECT     1: search defective pixels against the noise model (the auto test)
 *   SC_MASK       1: a plane of known bad pixels (a map file, the DNG's FixBadPixels opcodes)
 *   SC_DARK       1: a per-pixel dark level (DN) replaces the black level
 *   SC_FLAT       1: a per-pixel flat-field gain
 *   SC_TERMS      number of opcode gain terms (GainMap, FixVignetteRadial of OpcodeLists 1, 2)
 *   SC_GRID       1: divide by the smooth gain G (applied after the chroma stage by sensor_shade)
 *   SC_K, SC_ALPHA, SC_GAMMA   the auto test's constants (float literals)
 *   SC_TERM_SIZE  floats per packed gain term
 */

#include "sensor.h"

/* sensor_correct: one pass over the mosaic, the steps in the DNG's order (halo SC_HALO = 2):
 *   1. w(q) = raw(q) g1(q) - off(q): OpcodeList1's gains on the stored value, then the dark frame
 *      (or the black level) subtracted; u = w / (white - black_c), the normalised value.
 *   2. bad pixel: known (mask), or found (SC_DETECT) where u_p lies beyond every same-channel
 *      neighbour by SC_K noise sigmas (the sensor model at that neighbour's level) plus SC_ALPHA
 *      times their spread, and its 4 nearest pixels (any channel, white-balanced) carry less than
 *      SC_GAMMA of its excess over the 5 x 5 ring (a hot pixel does not light its neighbours);
 *      replaced by the mean of the opposite same-channel pair that differs least (along an edge),
 *      else by the mean of the good neighbours.
 *   3. out = w_p r(p) out_scale_c + out_offset_c, r = flat(p) g2(p) / G_c(p): the flat field and
 *      OpcodeList2's gains, less the smooth part that sensor_shade applies after the chroma stage.
 * src: the window (width + 4) x (height + 4); mask, dark, flat: the same window of those planes;
 * (oy, ox): image coordinate of the window's pixel (0, 0); dst: width x height float.
 * Tables per CFA phase k = py CFA_PERIOD + px: nb_n[k] neighbours at nb[k][i] = (dy, dx) (chars),
 * pairs_n[k] opposite pairs pairs[k][j] = (i, i') (indices into nb[k]). Neighbours outside the
 * img_h x img_w image are left out (the mirrored padding puts the pixel itself among them). */
__kernel void sensor_correct(__global const RAW_T *restrict src, __global float *restrict dst,
                             const int width, const int height, const int oy, const int ox,
                             __constant const char *restrict pattern,
                             __constant const char *restrict nb, __constant const char *restrict nb_n,
                             __constant const char *restrict pairs, __constant const char *restrict pairs_n,
                             __constant const float *restrict black, __constant const float *restrict inv_range,
                             __constant const float *restrict out_scale, __constant const float *restrict out_offset,
                             __constant const float *restrict noise_a, __constant const float *restrict noise_b,
                             __constant const float *restrict wb,
                             __global const ushort *restrict mask, __global const float *restrict dark,
                             __global const float *restrict flat,
                             __constant const float *restrict terms, __global const float *restrict maps,
                             __global const float *restrict grid, const int gh, const int gw, const float inv_cell,
                             __global uint *restrict found, const int img_h, const int img_w)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    const int sw = width + 2 * SC_HALO;
    const int iy = y + SC_HALO, ix = x + SC_HALO;            /* in the window */
    const int gy = iy + oy, gx = ix + ox;                     /* in the image */
    const int py = ((gy % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD, px = ((gx % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD;
    const int k = py * CFA_PERIOD + px;
    const int c = pattern[k];
    const int i = iy * sw + ix;
#if SC_TERMS
    const float g1 = list_gain(terms, maps, 1, gy, gx);
#else
    const float g1 = 1.0f;
#endif
#if SC_DARK
    float w = (float)src[i] * g1 - dark[i];
#else
    float w = (float)src[i] * g1 - black[c];
#endif
#if SC_MASK
    int bad = mask[i] != 0;
#else
    int bad = 0;
#endif
    const int n = nb_n[k];
    __constant const char *o = nb + 2 * k * SC_NB_MAX;
#define OUTSIDE(j) (gy + o[2 * (j)] < 0 || gy + o[2 * (j)] >= img_h || gx + o[2 * (j) + 1] < 0 || gx + o[2 * (j) + 1] >= img_w)
#if SC_DETECT
    if (!bad && n > 0) {
        float hi = -INFINITY, lo = INFINITY;
        int used = 0;
        for (int j = 0; j < n; j++) {
            const int q = i + o[2 * j] * sw + o[2 * j + 1];
            if (OUTSIDE(j))
                continue;
#if SC_MASK
            if (mask[q])
                continue;
#endif
#if SC_DARK
            const float wq = (float)src[q] * g1 - dark[q];
#else
            const float wq = (float)src[q] * g1 - black[c];
#endif
            hi = fmax(hi, wq);
            lo = fmin(lo, wq);
            used++;
        }
        const float s = inv_range[c];
        const float up = w * s, uhi = hi * s, ulo = lo * s;
        const float spread = SC_ALPHA * (uhi - ulo);
        const float hot = up - uhi - SC_K * sqrt(noise_a[c] * fmax(uhi, 0.0f) + noise_b[c]) - spread;
        const float cold = ulo - up - SC_K * sqrt(noise_a[c] * fmax(ulo, 0.0f) + noise_b[c]) - spread;
        if (used && (hot > 0.0f || cold > 0.0f)) {
            /* the support test: the 4 nearest pixels against the ring at distance 2, white-balanced */
            float axial = 0.0f, ring = 0.0f;
            for (int dy = -2; dy <= 2; dy++) {
                for (int dx = -2; dx <= 2; dx++) {
                    const int ady = abs(dy), adx = abs(dx);
                    if (ady + adx == 0 || (ady <= 1 && adx <= 1 && ady + adx == 2))
                        continue;
                    const int cq = pattern[((gy + dy) % CFA_PERIOD + CFA_PERIOD) % CFA_PERIOD * CFA_PERIOD
                                           + ((gx + dx) % CFA_PERIOD + CFA_PERIOD) % CFA_PERIOD];
                    const int q = i + dy * sw + dx;
#if SC_DARK
                    const float v = ((float)src[q] * g1 - dark[q]) * inv_range[cq] * wb[cq];
#else
                    const float v = ((float)src[q] * g1 - black[cq]) * inv_range[cq] * wb[cq];
#endif
                    if (ady + adx == 1)
                        axial += v;
                    else
                        ring += v;
                }
            }
            axial *= 0.25f;
            ring *= 1.0f / 16.0f;
            const float excess = up * wb[c] - ring;
            bad = fabs(excess) > 0.0f && (axial - ring) / excess < SC_GAMMA;
            if (bad)
                atomic_inc(found);
        }
    }
#endif
    if (bad) {
        /* the opposite same-channel pair that differs least, else the good neighbours' mean */
        float best = INFINITY, est = 0.0f, sum = 0.0f;
        int good = 0;
        __constant const char *pr = pairs + 2 * k * SC_PAIRS_MAX;
        for (int j = 0; j < pairs_n[k]; j++) {
            const int a = pr[2 * j], b = pr[2 * j + 1];
            const int qa = i + o[2 * a] * sw + o[2 * a + 1], qb = i + o[2 * b] * sw + o[2 * b + 1];
            if (OUTSIDE(a) || OUTSIDE(b))
                continue;
#if SC_MASK
            if (mask[qa] || mask[qb])
                continue;
#endif
#if SC_DARK
            const float wa = (float)src[qa] * g1 - dark[qa], wb_ = (float)src[qb] * g1 - dark[qb];
#else
            const float wa = (float)src[qa] * g1 - black[c], wb_ = (float)src[qb] * g1 - black[c];
#endif
            const float d = fabs(wa - wb_);
            if (d < best) {
                best = d;
                est = 0.5f * (wa + wb_);
            }
        }
        if (best == INFINITY) {
            for (int j = 0; j < n; j++) {
                const int q = i + o[2 * j] * sw + o[2 * j + 1];
                if (OUTSIDE(j))
                    continue;
#if SC_MASK
                if (mask[q])
                    continue;
#endif
#if SC_DARK
                sum += (float)src[q] * g1 - dark[q];
#else
                sum += (float)src[q] * g1 - black[c];
#endif
                good++;
            }
            if (good)
                est = sum / (float)good;
            else
                est = w;
        }
        w = est;
    }
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
    dst[y * width + x] = w * r * out_scale[c] + out_offset[c];
}
