/* DLMMSE demosaic (Zhang & Wu 2005, as Getreuer documents it); NumPy reference and step list in
 * clisp/modules/demosaic_dlmmse/stage.py, one kernel per step with the same names.
 *
 * Defines from the host:
 *   CFA_PERIOD (2); CFA_PATTERN, the 2 x 2 Bayer pattern as seen from the input window,
 *   {c00,c01,c10,c11}: entry [0][0] is the channel of window pixel (0, 0) (all radii are even, so
 *   every step's window starts on that same phase); RED, GREEN, BLUE (channel indices);
 *   INTERP_RADIUS, INTERP_WEIGHTS (Hamilton-Adams filter); SMOOTH_RADIUS, SMOOTH_WEIGHTS;
 *   WINDOW_RADIUS (M), EPSILON, WINDOW_MEAN (0: mu = centre sample, 1: window mean);
 *   FILL_RADIUS (2: diagonal then axial fill); INTERLEAVED (0: 3 planes, 1: H x W x 3);
 *   RAW_T (input mosaic type: float, or ushort when this is the first stage).
 *
 * Each step's output window is its input window less its radius on every side: index (y, x) of a
 * step's output reads its input around (y + r, x + r).
 * Schedule (measured on a 24 MP mosaic, PoCL on 2 EPYC cores): one work-item per output pixel;
 * where the work depends on the CFA site every candidate is computed and one is picked with a
 * select, so there is no branch on per-pixel data and PoCL vectorises across work-items along x
 * (8 lanes). One 2 x 2 block per work-item (sites known at compile time, stride-2 accesses) did not
 * vectorise and was 2.1x slower in total; helpers are always_inline because a helper left as a
 * call stops vectorisation (lmmse_fuse: 0.55 s -> 0.17 s). The steps are bandwidth-bound except
 * lmmse_fuse, which computes at G sites too (discarded): cheaper than a branch that would not
 * vectorise. Every kernel is launched over exactly its output (launch_exact) and has no bounds
 * check, which would stop PoCL vectorising. */

__constant char cfa_pattern[CFA_PERIOD * CFA_PERIOD] = CFA_PATTERN;
__constant float interp_weights[2 * INTERP_RADIUS + 1] = INTERP_WEIGHTS;
__constant float smooth_weights[2 * SMOOTH_RADIUS + 1] = SMOOTH_WEIGHTS;

#define WINDOW_SIZE (2 * WINDOW_RADIUS + 1)

/* CFA channel of pixel (y, x) of a step's window. */
#define SITE(y, x) cfa_channel(cfa_pattern, y, x)

/* dlmmse_directional_differences: Hamilton-Adams interpolation along the row (F_H) and the column
 * (F_V), then G - X observed in each direction: d = cfa - F at G sites, F - cfa at R/B sites.
 * raw: 1 plane of out + 2 INTERP_RADIUS; diff: planes d_H, d_V. Halo INTERP_RADIUS (2). */
__kernel void dlmmse_directional_differences(__global const RAW_T *restrict raw, __global float *restrict diff,
                                             const int raw_w, const int out_w, const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    __global const RAW_T *centre = raw + (y + INTERP_RADIUS) * raw_w + x + INTERP_RADIUS;
    float f_h = 0.0f, f_v = 0.0f;
    #pragma unroll
    for (int k = -INTERP_RADIUS; k <= INTERP_RADIUS; ++k) {
        f_h += interp_weights[k + INTERP_RADIUS] * (float)centre[k];
        f_v += interp_weights[k + INTERP_RADIUS] * (float)centre[k * raw_w];
    }
    const float cfa = (float)centre[0];
    const float sign = SITE(y, x) == GREEN ? 1.0f : -1.0f;
    diff[y * out_w + x] = sign * (cfa - f_h);
    diff[out_w * out_h + y * out_w + x] = sign * (cfa - f_v);
}

/* dlmmse_smooth: s_H = d_H smoothed along the row, s_V = d_V along the column, with
 * SMOOTH_WEIGHTS. diff: planes d_H, d_V (in_w x in_h); smoothed: planes s_H, s_V.
 * Halo SMOOTH_RADIUS (4). */
__kernel void dlmmse_smooth(__global const float *restrict diff, __global float *restrict smoothed,
                            const int in_w, const int in_h, const int out_w, const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int at = (y + SMOOTH_RADIUS) * in_w + x + SMOOTH_RADIUS;
    __global const float *d_h = diff + at;
    __global const float *d_v = diff + in_w * in_h + at;
    float s_h = 0.0f, s_v = 0.0f;
    #pragma unroll
    for (int k = -SMOOTH_RADIUS; k <= SMOOTH_RADIUS; ++k) {
        s_h += smooth_weights[k + SMOOTH_RADIUS] * d_h[k];
        s_v += smooth_weights[k + SMOOTH_RADIUS] * d_v[k * in_w];
    }
    smoothed[y * out_w + x] = s_h;
    smoothed[out_w * out_h + y * out_w + x] = s_v;
}

/* LMMSE estimate of G - X along one direction, returned as (u, e): the estimate and its error
 * variance, from the WINDOW_SIZE samples of s and d around the centre, at strides s_step, d_step:
 *   mu = s[0] (or the window mean), sx2 = sample variance of s (= sum s^2/2M - (sum s)^2/(2M(2M+1))),
 *   sv2 = mean (s - d)^2 + EPSILON, u = mu + sx2/(sx2+sv2) (d[0] - mu),
 *   e = sx2 - sx2^2/(sx2+sv2) + EPSILON = sx2 sv2/(sx2+sv2) + EPSILON.
 * The variance is summed about the mean (same value, no float32 cancellation). */
__attribute__((always_inline)) inline float2 lmmse_direction(__global const float *s,
                                                             __global const float *d,
                                                             const int s_step, const int d_step)
{
    float sum = 0.0f;
    #pragma unroll
    for (int k = -WINDOW_RADIUS; k <= WINDOW_RADIUS; ++k)
        sum += s[k * s_step];
    const float mean = sum * (1.0f / WINDOW_SIZE);
    float sx2 = 0.0f, sv2 = 0.0f;
    #pragma unroll
    for (int k = -WINDOW_RADIUS; k <= WINDOW_RADIUS; ++k) {
        const float s_k = s[k * s_step];
        const float d_k = d[k * d_step];
        sx2 += (s_k - mean) * (s_k - mean);
        sv2 += (s_k - d_k) * (s_k - d_k);
    }
    sx2 *= 1.0f / (2 * WINDOW_RADIUS);
    sv2 = sv2 * (1.0f / WINDOW_SIZE) + EPSILON;
    const float mu = WINDOW_MEAN ? mean : s[0];
    const float gain = sx2 / (sx2 + sv2);
    return (float2)(mu + gain * (d[0] - mu), gain * sv2 + EPSILON);
}

/* dlmmse_lmmse_fuse: at R/B sites, Delta = G - X = (e_V u_H + e_H u_V) / (e_H + e_V) from the
 * horizontal and vertical LMMSE estimates; 0 at G sites (unused; computed there too and discarded,
 * which keeps the kernel branch-free). smoothed: planes s_H, s_V (out + 2 WINDOW_RADIUS);
 * diff: planes d_H, d_V (out + 4 WINDOW_RADIUS); delta: 1 plane. Halo WINDOW_RADIUS (4). */
__kernel void dlmmse_lmmse_fuse(__global const float *restrict smoothed, __global const float *restrict diff,
                                __global float *restrict delta, const int s_w, const int s_h,
                                const int d_w, const int d_h, const int out_w, const int out_h)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int s_at = (y + WINDOW_RADIUS) * s_w + x + WINDOW_RADIUS;
    const int d_at = (y + 2 * WINDOW_RADIUS) * d_w + x + 2 * WINDOW_RADIUS;
    const float2 h = lmmse_direction(smoothed + s_at, diff + d_at, 1, 1);            /* (u_H, e_H) */
    const float2 v = lmmse_direction(smoothed + s_w * s_h + s_at, diff + d_w * d_h + d_at, s_w, d_w);
    const float fused = (v.y * h.x + h.y * v.x) / (h.y + v.y);
    delta[y * out_w + x] = SITE(y, x) == GREEN ? 0.0f : fused;
}

/* G - c (c = RED or BLUE) at the R/B site p = (y, x) of the delta grid (row stride w): Delta itself
 * at a c site, else (the other colour's site) the mean of its 4 diagonal neighbours, c sites. */
__attribute__((always_inline)) inline float diff_at_rb(__global const float *p, const int w,
                                                       const int y, const int x, const int c)
{
    const float diagonal = 0.25f * (p[-w - 1] + p[-w + 1] + p[w - 1] + p[w + 1]);
    return SITE(y, x) == c ? p[0] : diagonal;
}

/* G - c at any site p = (y, x) of the delta grid: diff_at_rb at R/B sites; at G sites the mean of
 * diff_at_rb over the 4 axial neighbours (R/B sites). */
__attribute__((always_inline)) inline float diff_at(__global const float *p, const int w, const int y,
                                                    const int x, const int c)
{
    const float axial = 0.25f * (diff_at_rb(p - w, w, y - 1, x, c) + diff_at_rb(p + w, w, y + 1, x, c)
                               + diff_at_rb(p - 1, w, y, x - 1, c) + diff_at_rb(p + 1, w, y, x + 1, c));
    return SITE(y, x) == GREEN ? axial : diff_at_rb(p, w, y, x, c);
}

/* dlmmse_complete_rgb: G = X + Delta at R/B sites (the sample at G sites); G - R and G - B
 * completed diagonally (diff_at_rb) then, at G sites, axially (mean of the 4 neighbours'
 * diff_at_rb); R = G - (G - R), B = G - (G - B); measured samples are written as they are.
 * Then out = m (R, G, B) (m: 3 x 3, identity unless a colour matrix was fused in).
 * raw: the step-1 input (out + 24); delta: out + 2 FILL_RADIUS. Halo FILL_RADIUS (2). */
__kernel void dlmmse_complete_rgb(__global const RAW_T *restrict raw, __global const float *restrict delta,
                                  __global float *restrict out, const int raw_w, const int delta_w,
                                  const int out_w, const int out_h, __constant const float *restrict m)
{
    const int x = inward_id(0, out_w - 1);
    const int y = inward_id(1, out_h - 1);
    const int raw_offset = (raw_w - out_w) / 2;
    const float cfa = (float)raw[(y + raw_offset) * raw_w + x + raw_offset];
    const int w = delta_w, dy = y + FILL_RADIUS, dx = x + FILL_RADIUS;
    __global const float *p = delta + dy * w + dx;
    const int site = SITE(dy, dx);
    const float g = site == GREEN ? cfa : cfa + p[0];
    const float r = site == RED ? cfa : g - diff_at(p, w, dy, dx, RED);
    const float b = site == BLUE ? cfa : g - diff_at(p, w, dy, dx, BLUE);
    const float rgb[3] = {m[0] * r + m[1] * g + m[2] * b,
                          m[3] * r + m[4] * g + m[5] * b,
                          m[6] * r + m[7] * g + m[8] * b};
    #pragma unroll
    for (int c = 0; c < 3; ++c)
        out[INTERLEAVED ? (y * out_w + x) * 3 + c : c * out_w * out_h + y * out_w + x] = rgb[c];
}
