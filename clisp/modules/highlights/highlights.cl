/* Highlight handling on planar white-balanced camera channels (clisp/modules/highlights/stage.py has
 * the definitions and the NumPy reference). n: the neutral (3), t: the clip thresholds in units
 * of n (3). Launched over exactly the output (launch_exact): no bounds checks. */

/* The reconstruct/clip kernels need the host's constants (clisp/modules/highlights/stage.py, as
 * defines): HL_RADIUS, HL_RIM, HL_BLOCK, HL_CLIP, HL_REF, HL_LOW, HL_PRIOR, HL_DIP, HL_RHO_MIN,
 * HL_AGREE_LO, HL_AGREE_HI, HL_RISE_LO, HL_RISE_HI, HL_EVIDENCE, HL_SUMS, HL_CELL, HL_CELL_R and
 * the reach levels HL_D_APPLY, HL_D_CELLS, HL_D_NEAR, HL_D_NEAR_ROWS. Built without them (the clamp alone), the file holds hl_clamp only. */
#ifdef HL_RADIUS

#include "box.h"

/* Windows: src (width x height) -> flags (same) -> near rows (w1 = width - 2 RIM columns) ->
 * near on the window less the rim (w1 x h1) -> reference sums per cell and over each cell's
 * neighbourhood (ncw x nch cells of the image's grid) -> output (ow x oh, w1 - 2 R x h1 - 2 R).
 * Output pixel (y, x) is src pixel (y + RIM + R, x + RIM + R). */

/* max without fmax: PoCL 3 does not vectorise fmax/fmin (3x slower kernels); inputs are finite. */
inline float hl_max(const float a, const float b)
{
    return a > b ? a : b;
}

inline int any_clipped(const float y0, const float y1, const float y2, __constant const float *t)
{
    return y0 >= t[0] || y1 >= t[1] || y2 >= t[2];
}

/* soft_clipped: channel c (plane at src + offset) at src index i, not clipped itself, counts as
 * clipped when y_c >= HL_DIP t_c and y_c >= t_c at one of the 8 neighbours (the caller has
 * another channel clipped at i: highlights.clipped_channels, and keeps i one pixel inside the
 * window). */
inline int soft_clipped(__global const float *src, const int i, const int width, const float inv_n,
                        const float t)
{
    if (src[i] * inv_n < HL_DIP * t)
        return 0;
    float m = 0.0f;
    for (int dy = -1; dy <= 1; dy++)
        for (int dx = -1; dx <= 1; dx++)
            m = hl_max(m, src[i + dy * width + dx]);
    return m * inv_n >= t;
}

/* hl_flags: 1 where a channel of the pixel reached its threshold, else 0. */
__kernel void hl_flags(__global const float *restrict src, __global float *restrict dst,
                       const int width, const int height, __constant const float *restrict n,
                       __constant const float *restrict t)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int plane = width * height;
    const int i = y * width + x;
    dst[i] = any_clipped(src[i] / n[0], src[plane + i] / n[1], src[2 * plane + i] / n[2], t) ? 1.0f : 0.0f;
}

/* Sparsity: the stage changes only pixels within RIM of a clipped one, so every kernel after
 * hl_flags works only where a clipped pixel lies near enough for its result to be read.
 * hl_blocks: blocks (nby x nbx, HL_BLOCK px of the src window each) = 1 where the block holds a
 * clipped pixel. hl_reach: plane d - 1 (d = 1..4) = 1 where a block within d blocks does. A
 * kernel whose output pixel lies in src block (by, bx) works when reach[d][by][bx] is set, d the
 * host's level for that kernel (highlights.reach_levels): apply works within HL_D_APPLY blocks
 * (every pixel it changes lies within RIM of a clipped one) and reads the cell box sums of its
 * cell and near there; the cell box sums read cells up to (HL_CELL_R + 1) HL_CELL - 1 px away
 * (HL_D_CELLS), the cells read near at their pixels (HL_D_NEAR, a block more: a cell may straddle
 * a block edge), near reads the near rows RIM rows away (HL_D_NEAR_ROWS); nothing a working pixel
 * reads was skipped, whatever the pool's buffers held before. Skipped apply pixels are copied
 * unchanged. */
__kernel void hl_blocks(__global const float *restrict flags, __global float *restrict blocks,
                        const int width, const int height, const int nbx)
{
    const int bx = get_global_id(0);
    const int by = get_global_id(1);
    const int x0 = bx * HL_BLOCK, y0 = by * HL_BLOCK;
    const int x1 = min(x0 + HL_BLOCK, width), y1 = min(y0 + HL_BLOCK, height);
    float m = 0.0f;
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++)
            m = hl_max(m, flags[y * width + x]);
    blocks[by * nbx + bx] = m;
}

__kernel void hl_reach(__global const float *restrict blocks, __global float *restrict reach,
                       const int nbx, const int nby)
{
    const int bx = get_global_id(0);
    const int by = get_global_id(1);
    for (int d = 1; d <= 4; d++) {
        float m = 0.0f;
        for (int j = max(by - d, 0); j <= min(by + d, nby - 1); j++)
            for (int i = max(bx - d, 0); i <= min(bx + d, nbx - 1); i++)
                m = hl_max(m, blocks[j * nbx + i]);
        reach[((d - 1) * nby + by) * nbx + bx] = m;
    }
}

/* active: whether src pixel (sx, sy) lies in a block with reach[d] set. */
inline int active(__global const float *reach, const int d, const int sx, const int sy, const int nbx,
                  const int nby)
{
    return reach[((d - 1) * nby + sy / HL_BLOCK) * nbx + sx / HL_BLOCK] > 0.0f;
}

/* hl_near_rows: max of the flags over 2 RIM + 1 consecutive columns. */
__kernel void hl_near_rows(__global const float *restrict src, __global float *restrict dst,
                           const int width, const int out_w, __global const float *restrict reach,
                           const int nbx, const int nby)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (!active(reach, HL_D_NEAR_ROWS, x + HL_RIM, y, nbx, nby))
        return;
    float m = 0.0f;
    for (int k = 0; k <= 2 * HL_RIM; k++)
        m = hl_max(m, src[y * width + x + k]);
    dst[y * out_w + x] = m;
}

/* hl_near: on the window less the rim (w1 x h1): 1 where a pixel within RIM has a clipped
 * channel (max of the near rows over 2 RIM + 1 rows), else 0. */
__kernel void hl_near(__global const float *restrict rows, __global float *restrict dst, const int w1,
                      const int h1, __global const float *restrict reach, const int nbx, const int nby)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (!active(reach, HL_D_NEAR, x + HL_RIM, y + HL_RIM, nbx, nby))
        return;
    float near = 0.0f;
    for (int k = 0; k <= 2 * HL_RIM; k++)
        near = hl_max(near, rows[(y + k) * w1 + x]);
    dst[y * w1 + x] = near;
}

#if HL_RADIUS > 0
/* reference_weights: the HL_SUMS reference planes of highlights.reference_weights at src index i
 * (near: the pixel's near flag): (w, w rho0, w rho1, w mean(y)) of a far reference (bright,
 * clearly unclipped, not near), then (w, w rho0, w rho1) of a rim reference (near, no channel
 * clipped, bright); rho_c = y_c / mean(y). */
inline void reference_weights(__global const float *src, const int i, const int plane, const float near,
                              const float *inv_n, const float *inv_nt, float *w)
{
    const float x0 = src[i], x1 = src[plane + i], x2 = src[2 * plane + i];
    const float y0 = x0 * inv_n[0], y1 = x1 * inv_n[1], y2 = x2 * inv_n[2];
    const float m = hl_max(hl_max(x0 * inv_nt[0], x1 * inv_nt[1]), x2 * inv_nt[2]);
    const float ramp = clamp((m - HL_LOW) * (1.0f / (HL_REF - HL_LOW)), 0.0f, 1.0f);
    const float far = (m < HL_REF && near == 0.0f) ? ramp : 0.0f;
    const float rim = (near > 0.0f && m < 1.0f) ? ramp : 0.0f;
    const float total = y0 + y1 + y2;
    const float inv = total > 0.0f ? 3.0f / total : 0.0f;
    w[0] = far;
    w[1] = far * y0 * inv;
    w[2] = far * y1 * inv;
    w[3] = far * total * (1.0f / 3.0f);
    w[4] = rim;
    w[5] = rim * y0 * inv;
    w[6] = rim * y1 * inv;
}

/* cell_active: whether this work-item's cell (i, j) = (global id 0, 1), rows j HL_CELL - oy ..
 * + HL_CELL - 1 of the window less the rim (w1 x h1, cut at its edges), columns likewise, touches a
 * block with reach[d] set: its corners lie in every block it touches. span: the cell's first and
 * last column and row. */
inline int cell_active(__global const float *reach, const int d, const int ox, const int oy, const int w1,
                       const int h1, const int nbx, const int nby, int *span)
{
    const int i = get_global_id(0), j = get_global_id(1);
    const int x0 = max(i * HL_CELL - ox, 0), x1 = min(i * HL_CELL - ox + HL_CELL, w1) - 1;
    const int y0 = max(j * HL_CELL - oy, 0), y1 = min(j * HL_CELL - oy + HL_CELL, h1) - 1;
    span[0] = x0;
    span[1] = x1;
    span[2] = y0;
    span[3] = y1;
    return active(reach, d, x0 + HL_RIM, y0 + HL_RIM, nbx, nby) || active(reach, d, x1 + HL_RIM, y0 + HL_RIM, nbx, nby) ||
           active(reach, d, x0 + HL_RIM, y1 + HL_RIM, nbx, nby) || active(reach, d, x1 + HL_RIM, y1 + HL_RIM, nbx, nby);
}

/* hl_cells: the reference weights (reference_weights of src and near) summed over each cell of
 * HL_CELL x HL_CELL px of the window less the rim (w1 x h1); cells lie on the image's grid, the
 * window's first pixel at (oy, ox) of its cell, so cell (j, i) covers rows j HL_CELL - oy ..
 * + HL_CELL - 1 (cut at the window's edges). dst: HL_SUMS planes of nch x ncw cells. */
__kernel void hl_cells(__global const float *restrict src, __global const float *restrict near,
                       __global float *restrict dst, const int width, const int height, const int w1,
                       const int h1, const int ncw, const int nch, const int oy, const int ox,
                       __constant const float *restrict n, __constant const float *restrict t,
                       __global const float *restrict reach, const int nbx, const int nby)
{
    const int i = get_global_id(0);
    const int j = get_global_id(1);
    int span[4];
    if (!cell_active(reach, HL_D_CELLS, ox, oy, w1, h1, nbx, nby, span))
        return;
    const int plane = width * height, cplane = ncw * nch;
    const float inv_n[3] = {1.0f / n[0], 1.0f / n[1], 1.0f / n[2]};
    const float inv_nt[3] = {inv_n[0] / t[0], inv_n[1] / t[1], inv_n[2] / t[2]};
    float s[HL_SUMS], w[HL_SUMS];
    for (int p = 0; p < HL_SUMS; p++)
        s[p] = 0.0f;
    for (int y = span[2]; y <= span[3]; y++)
        for (int x = span[0]; x <= span[1]; x++) {
            reference_weights(src, (y + HL_RIM) * width + x + HL_RIM, plane, near[y * w1 + x], inv_n, inv_nt, w);
            for (int p = 0; p < HL_SUMS; p++)
                s[p] += w[p];
        }
    for (int p = 0; p < HL_SUMS; p++)
        dst[p * cplane + j * ncw + i] = s[p];
}

/* hl_cell_box: the sums of each cell's (2 HL_CELL_R + 1)^2 neighbourhood of cells (cells outside
 * the window count 0), HL_SUMS planes of nch x ncw, by the shared box sums (box.h); only cells
 * holding a pixel where hl_apply works. */
__kernel void hl_cell_box(__global const float *restrict cells, __global float *restrict dst, const int ncw,
                          const int nch, const int w1, const int h1, const int oy, const int ox,
                          __global const float *restrict reach, const int nbx, const int nby)
{
    int span[4];
    if (!cell_active(reach, HL_D_APPLY, ox, oy, w1, h1, nbx, nby, span))
        return;
    const int i = get_global_id(0), j = get_global_id(1), cplane = ncw * nch;
    const int i0 = max(i - HL_CELL_R, 0), i1 = min(i + HL_CELL_R, ncw - 1);
    const int j0 = max(j - HL_CELL_R, 0), j1 = min(j + HL_CELL_R, nch - 1);
    for (int p = 0; p < HL_SUMS; p++)
        dst[p * cplane + j * ncw + i] = box_sum_rect(cells + p * cplane, ncw, i0, i1, j0, j1);
}
#endif /* HL_RADIUS > 0 */

/* chroma_of: rho^ (mean 1) from box sums (w, w rho0, w rho1) and the neutral prior. */
inline void chroma_of(const float s0, const float s1, const float s2, float *rho)
{
    const float sw = s0 + HL_PRIOR;
    rho[0] = (s1 + HL_PRIOR) / sw;
    rho[1] = (s2 + HL_PRIOR) / sw;
    rho[2] = (3.0f * s0 - s1 - s2 + HL_PRIOR) / sw;
}

/* agreement: 1 where chromas a and b differ by at most HL_AGREE_LO in every output channel
 * (d (a - b), d the display matrix, row-major), 0 from HL_AGREE_HI, linear between. */
inline float agreement(const float *a, const float *b, __constant const float *d)
{
    const float e0 = a[0] - b[0], e1 = a[1] - b[1], e2 = a[2] - b[2];
    float dist = 0.0f;
    for (int r = 0; r < 3; r++)
        dist = hl_max(dist, fabs(d[3 * r] * e0 + d[3 * r + 1] * e1 + d[3 * r + 2] * e2));
    return clamp((HL_AGREE_HI - dist) / (HL_AGREE_HI - HL_AGREE_LO), 0.0f, 1.0f);
}

/* hl_apply: the rule of highlights.py at output pixel (y, x). HL_CLIP: clipped -> white n,
 * near -> neutral at the mean. Else the reconstruction: box: hl_cell_box's sums (ncw x nch cells,
 * far then rim, HL_SUMS planes) at the pixel's cell, read where the pixel is clipped or near; d
 * the display matrix of agreement(). */
__kernel void hl_apply(__global const float *restrict src, __global const float *restrict nearby,
                       __global const float *restrict box, __global float *restrict dst,
                       const int width, const int height, const int w1, const int ncw, const int nch,
                       const int oy, const int ox, const int out_w, const int out_h,
                       __constant const float *restrict n, __constant const float *restrict t,
                       __constant const float *restrict d, const float white,
                       __global const float *restrict reach, const int nbx, const int nby)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int plane = width * height, oplane = out_w * out_h;
    const int i = (y + HL_RIM + HL_RADIUS) * width + x + HL_RIM + HL_RADIUS;
    if (!active(reach, 1, x + HL_RIM + HL_RADIUS, y + HL_RIM + HL_RADIUS, nbx, nby)) {
        const int o = y * out_w + x;                  /* nothing clipped within RIM: unchanged */
        dst[o] = src[i];
        dst[oplane + o] = src[plane + i];
        dst[2 * oplane + o] = src[2 * plane + i];
        return;
    }
    float v[3] = {src[i] / n[0], src[plane + i] / n[1], src[2 * plane + i] / n[2]};
    int c0 = v[0] >= t[0], c1 = v[1] >= t[1], c2 = v[2] >= t[2];
    if (c0 + c1 + c2 > 0) {
        c0 = c0 || soft_clipped(src, i, width, 1.0f / n[0], t[0]);
        c1 = c1 || soft_clipped(src + plane, i, width, 1.0f / n[1], t[1]);
        c2 = c2 || soft_clipped(src + 2 * plane, i, width, 1.0f / n[2], t[2]);
    }
    const int count = c0 + c1 + c2;
    const float near = nearby[(y + HL_RADIUS) * w1 + x + HL_RADIUS];
#if HL_CLIP
    if (count > 0) {
        v[0] = v[1] = v[2] = white;
    } else if (near > 0.0f) {
        const float mean = (v[0] + v[1] + v[2]) / 3.0f;
        v[0] = v[1] = v[2] = mean;
    }
#else
    if (count == 3) {
        const float top = hl_max(hl_max(v[0], v[1]), v[2]);
        v[0] = v[1] = v[2] = top;
    } else if (count > 0 || near > 0.0f) {
        const int cell = ((y + HL_RADIUS + oy) / HL_CELL) * ncw + (x + HL_RADIUS + ox) / HL_CELL;
        float s[HL_SUMS];
        for (int p = 0; p < HL_SUMS; p++)
            s[p] = box[p * ncw * nch + cell];
        float far[3], rim[3];
        chroma_of(s[0], s[1], s[2], far);
        chroma_of(s[4], s[5], s[6], rim);
        const int clipped[3] = {c0, c1, c2};
        /* trust in the far chroma (highlights.trust_in_far) */
        float trust = agreement(far, rim, d);
        float fy[3], fr[3], sy = 0.0f, sr = 0.0f;
        for (int c = 0; c < 3; c++) {
            fy[c] = clipped[c] ? 0.0f : v[c];
            fr[c] = clipped[c] ? 0.0f : far[c];
            sy += fy[c];
            sr += fr[c];
        }
        if (count == 1) {                    /* the pixel's two free channels against far */
            const float scale = sr / hl_max(sy, 1e-9f);
            float sc[3];
            for (int c = 0; c < 3; c++)
                sc[c] = fy[c] * scale;
            trust *= agreement(sc, fr, d);
        }
        if (count > 0) {                     /* the brightness far implies, against its references' */
            const float implied = sy / hl_max(sr, 1e-6f);
            const float rise = s[0] > 0.0f ? implied * s[0] / hl_max(s[3], 1e-9f) : 0.0f;
            trust *= clamp((HL_RISE_HI - rise) / (HL_RISE_HI - HL_RISE_LO), 0.0f, 1.0f);
        }
        float rho[3];
        for (int c = 0; c < 3; c++)
            rho[c] = 1.0f + trust * (far[c] - 1.0f);
        if (count == 0) {                    /* rim: reference colour, unless a surface of its own */
            const float mean = (v[0] + v[1] + v[2]) / 3.0f;
            float own[3];
            for (int c = 0; c < 3; c++)
                own[c] = mean > 0.0f ? v[c] / mean : 1.0f;
            const float keep = s[0] / (s[0] + HL_EVIDENCE) * (1.0f - agreement(own, far, d));
            for (int c = 0; c < 3; c++)
                v[c] += (1.0f - keep) * (mean * rho[c] - v[c]);
        } else {
            float den = 0.0f;
            for (int c = 0; c < 3; c++)
                if (!clipped[c])
                    den += rho[c];
            float k = sy / hl_max(den, 1e-6f);
            for (int c = 0; c < 3; c++)          /* a clipped record bounds the brightness below */
                if (clipped[c] && rho[c] >= HL_RHO_MIN)
                    k = hl_max(k, v[c] / rho[c]);
            for (int c = 0; c < 3; c++)
                if (clipped[c])
                    v[c] = hl_max(v[c], k * rho[c]);
        }
    }
#endif
    const int o = y * out_w + x;
    dst[o] = v[0] * n[0];
    dst[oplane + o] = v[1] * n[1];
    dst[2 * oplane + o] = v[2] * n[2];
}

#endif /* HL_RADIUS */

/* hl_clamp: dst_c = min(src_c, cap_c), cap = s n (HighlightClamp, preset fast); MATRIX 1 then
 * applies the 3 x 3 matrix m (the colour matrix that follows, fused). Halo 0. */
__kernel void hl_clamp(__global const float *restrict src, __global float *restrict dst, const int width,
                       const int height, const float cap0, const float cap1, const float cap2,
                       __constant const float *restrict m)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int plane = width * height;
    const int i = y * width + x;
    const float a0 = src[i], b0 = src[plane + i], c0 = src[2 * plane + i];
    const float a = a0 < cap0 ? a0 : cap0, b = b0 < cap1 ? b0 : cap1, c = c0 < cap2 ? c0 : cap2;   /* not fmin: PoCL does not vectorise it */
#if MATRIX
    dst[i]             = m[0] * a + m[1] * b + m[2] * c;
    dst[plane + i]     = m[3] * a + m[4] * b + m[5] * c;
    dst[2 * plane + i] = m[6] * a + m[7] * b + m[8] * c;
#else
    dst[i] = a;
    dst[plane + i] = b;
    dst[2 * plane + i] = c;
#endif
}
