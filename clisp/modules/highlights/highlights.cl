/* Highlight handling on planar white-balanced camera channels (clisp/modules/highlights/stage.py has
 * the definitions and the NumPy reference). n: the neutral (3), t: the clip thresholds in units
 * of n (3). */

/* The reconstruct/clip kernels need the host's constants (clisp/modules/highlights/stage.py, as
 * defines): HL_RADIUS, HL_RIM, HL_MC, HL_WC, HL_CLIP, HL_REF, HL_LOW, HL_PRIOR, HL_DIP, HL_MARGIN,
 * HL_RHO_MIN, HL_AGREE_LO, HL_AGREE_HI, HL_RISE_LO, HL_RISE_HI, HL_EVIDENCE, HL_SUMS, HL_CELL, HL_CELL_R,
 * HL_WORK_CELLS, HL_WORK_ROWS, HL_WORK_BOX. Built without them (the clamp alone), the file holds hl_clamp only. */
#ifdef HL_RADIUS

#include "box.h"

/* Windows: src (width x height) -> flags (same, uchar: bit c = channel c clipped) -> near rows
 * (w1 = width - 2 RIM columns) -> near on the window less the rim (w1 x h1, uchar) -> reference
 * sums per cell and over each cell's neighbourhood (ncw x nch cells of the image's grid) ->
 * output (ow x oh, w1 - 2 R x h1 - 2 R). Output pixel (y, x) is src pixel (y + RIM + R, x + RIM + R).
 *
 * Work in proportion to the clipped area: the host's clip map (Highlights.schedule) gives the
 * window's map cells (HL_MC x HL_MC px on the image's grid: window pixel (y, x) lies in cell
 * ((y + py) / HL_MC, (x + px) / HL_MC)) with the channels that may count as clipped there (bits
 * 0-2), the lists of HL_WC x HL_WC px work cells for the list kernels and the work of the cell
 * kernels per reference cell (HL_WORK_CELLS, HL_WORK_ROWS, HL_WORK_BOX). hl_copy copies the whole
 * output; the list kernels (hl_flags, hl_near_rows, hl_near, hl_apply) run one work-group of
 * HL_WC x HL_WC per listed cell (entries gy << 16 | gx): flags only where a channel is allowed
 * (0 elsewhere, hl_clear), near within a map cell of those (every pixel within RIM <= HL_MC of a
 * flag; 0 elsewhere), the near rows a map cell above and below that, apply where near; the cell
 * kernels run over the grid of reference cells and leave at once outside their work. */

/* max without fmax: PoCL 3 does not vectorise fmax/fmin (3x slower kernels); inputs are finite. */
inline float hl_max(const float a, const float b)
{
    return a > b ? a : b;
}

/* list_pixel: this work-item's window pixel (x, y): work cell get_global_id(1) / HL_WC of the
 * list (HL_WC px on the image's grid, the window's first pixel at (wy, wx) of its cell), its pixel
 * (get_global_id(0), get_global_id(1) % HL_WC). */
inline int2 list_pixel(__global const int *list, const int wy, const int wx)
{
    const int c = list[get_global_id(1) / HL_WC];
    return (int2)((c & 0xffff) * HL_WC + (int)get_global_id(0) - wx,
                  (c >> 16) * HL_WC + (int)(get_global_id(1) % HL_WC) - wy);
}

/* hl_copy: the output, the window less RIM + R on every side (hl_apply overwrites where it works). */
__kernel void hl_copy(__global const float *restrict src, __global float *restrict dst, const int width,
                      const int height, const int out_w, const int out_h)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int i = (y + HL_RIM + HL_RADIUS) * width + x + HL_RIM + HL_RADIUS, plane = width * height;
    const int o = y * out_w + x, oplane = out_w * out_h;
    dst[o] = src[i];
    dst[oplane + o] = src[plane + i];
    dst[2 * oplane + o] = src[2 * plane + i];
}

/* hl_clear: 0 in every byte of a width-wide plane. */
__kernel void hl_clear(__global uchar *restrict dst, const int width)
{
    dst[get_global_id(1) * width + get_global_id(0)] = 0;
}

/* hl_flags (list: the cells where a channel is allowed): bit c where y_c >= t_c and the cell allows c. */
__kernel void hl_flags(__global const int *restrict list, __global const float *restrict src,
                       __global const uchar *restrict cells, __global uchar *restrict dst, const int width,
                       const int height, const int ngx, const int py, const int px,
                       __constant const float *restrict n, __constant const float *restrict t, const int wy,
                       const int wx)
{
    const int2 p = list_pixel(list, wy, wx);
    if (p.x < 0 || p.y < 0 || p.x >= width || p.y >= height)
        return;
    const int bits = cells[((p.y + py) / HL_MC) * ngx + (p.x + px) / HL_MC];
    const int plane = width * height, i = p.y * width + p.x;
    uchar f = 0;
    if ((bits & 1) && src[i] / n[0] >= t[0])
        f |= 1;
    if ((bits & 2) && src[plane + i] / n[1] >= t[1])
        f |= 2;
    if ((bits & 4) && src[2 * plane + i] / n[2] >= t[2])
        f |= 4;
    dst[i] = f;
}

/* hl_near_rows (list): 1 where a flag lies within RIM columns (the window less RIM columns, w1 wide). */
__kernel void hl_near_rows(__global const int *restrict list, __global const uchar *restrict flags,
                           __global uchar *restrict dst, const int width, const int height, const int w1,
                           const int wy, const int wx)
{
    const int2 p = list_pixel(list, wy, wx);
    const int x = p.x - HL_RIM;
    if (x < 0 || x >= w1 || p.y < 0 || p.y >= height)
        return;
    uchar m = 0;
    for (int k = 0; k <= 2 * HL_RIM; k++)
        m |= flags[p.y * width + x + k];
    dst[p.y * w1 + x] = m != 0;
}

/* hl_near (list): on the window less the rim (w1 x h1): 1 where a pixel within RIM has a clipped
 * channel (max of the near rows over 2 RIM + 1 rows). */
__kernel void hl_near(__global const int *restrict list, __global const uchar *restrict rows,
                      __global uchar *restrict dst, const int w1, const int h1, const int wy, const int wx)
{
    const int2 p = list_pixel(list, wy, wx);
    const int x = p.x - HL_RIM, y = p.y - HL_RIM;
    if (x < 0 || y < 0 || x >= w1 || y >= h1)
        return;
    uchar m = 0;
    for (int k = 0; k <= 2 * HL_RIM; k++)
        m |= rows[(y + k) * w1 + x];
    dst[y * w1 + x] = m;
}

#if HL_RADIUS > 0
/* reference_weights: the HL_SUMS reference planes of highlights.reference_weights at src index i
 * (near: the pixel's near flag): (w, w rho0, w rho1, w mean(y)) of a far reference (bright,
 * clearly unclipped, not near), (w, w rho0, w rho1, w (y0 - mean), w (y1 - mean)) of a rim
 * reference (near, no channel clipped, bright), (w, w rho0, w rho1) of a surface reference (not
 * near, clearly unclipped, not among the darkest); rho_c = y_c / mean(y). */
inline void reference_weights(__global const float *src, const int i, const int plane, const uchar near,
                              const float *inv_n, const float *inv_nt, float *w)
{
    const float x0 = src[i], x1 = src[plane + i], x2 = src[2 * plane + i];
    const float y0 = x0 * inv_n[0], y1 = x1 * inv_n[1], y2 = x2 * inv_n[2];
    const float m = hl_max(hl_max(x0 * inv_nt[0], x1 * inv_nt[1]), x2 * inv_nt[2]);
    const float ramp = clamp((m - HL_LOW) * (1.0f / (HL_REF - HL_LOW)), 0.0f, 1.0f);
    const float far = (m < HL_REF && near == 0) ? ramp : 0.0f;
    const float rim = (near != 0 && m < 1.0f) ? ramp : 0.0f;
    const float surface = (m < HL_REF && near == 0) ?
        clamp((m - HL_SURFACE_LOW) * (1.0f / (HL_SURFACE_FULL - HL_SURFACE_LOW)), 0.0f, 1.0f) : 0.0f;
    const float total = y0 + y1 + y2, mean = total * (1.0f / 3.0f);
    const float inv = total > 0.0f ? 3.0f / total : 0.0f;
    w[0] = far;
    w[1] = far * y0 * inv;
    w[2] = far * y1 * inv;
    w[3] = far * mean;
    w[4] = rim;
    w[5] = rim * y0 * inv;
    w[6] = rim * y1 * inv;
    w[7] = rim * (y0 - mean);
    w[8] = rim * (y1 - mean);
    w[9] = surface;
    w[10] = surface * y0 * inv;
    w[11] = surface * y1 * inv;
}

/* hl_cells: the reference weights (reference_weights of src and near) of HL_SAMPLES pixels of
 * each cell of HL_CELL x HL_CELL px of the window less the rim (w1 x h1), summed: the pixels
 * (HL_SAMPLE_Y, HL_SAMPLE_X) of the cell (highlights.SAMPLES), those inside the window less the rim.
 * Cells lie on the image's grid, the window's first pixel at (oy, ox) of its cell, so cell (j, i)
 * starts at row j HL_CELL - oy, column i HL_CELL - ox. dst: HL_SUMS planes of nch x ncw cells, at
 * the cells with HL_WORK_CELLS (those hl_box_rows reads). */
__kernel void hl_cells(__global const float *restrict src, __global const uchar *restrict near,
                       __global float *restrict dst, const int width, const int height, const int w1,
                       const int h1, const int ncw, const int nch, const int oy, const int ox,
                       __constant const float *restrict n, __constant const float *restrict t,
                       __global const uchar *restrict cells)
{
    const int sample_y[HL_SAMPLES] = HL_SAMPLE_Y, sample_x[HL_SAMPLES] = HL_SAMPLE_X;
    const int i = get_global_id(0);
    const int j = get_global_id(1);
    if (!(cells[j * ncw + i] & HL_WORK_CELLS))
        return;
    const int plane = width * height, cplane = ncw * nch;
    const float inv_n[3] = {1.0f / n[0], 1.0f / n[1], 1.0f / n[2]};
    const float inv_nt[3] = {inv_n[0] / t[0], inv_n[1] / t[1], inv_n[2] / t[2]};
    float s[HL_SUMS], w[HL_SUMS];
    for (int q = 0; q < HL_SUMS; q++)
        s[q] = 0.0f;
    for (int k = 0; k < HL_SAMPLES; k++) {
        const int y = j * HL_CELL - oy + sample_y[k], x = i * HL_CELL - ox + sample_x[k];
        if (x < 0 || y < 0 || x >= w1 || y >= h1)
            continue;
        reference_weights(src, (y + HL_RIM) * width + x + HL_RIM, plane, near[y * w1 + x], inv_n, inv_nt, w);
        for (int q = 0; q < HL_SUMS; q++)
            s[q] += w[q];
    }
    for (int q = 0; q < HL_SUMS; q++)
        dst[q * cplane + j * ncw + i] = s[q];
}

/* hl_box_rows: the sums of each cell's 2 HL_CELL_R + 1 cells along its row of cells (cells outside
 * the window count 0), HL_SUMS planes of nch x ncw, at the cells with HL_WORK_ROWS (those
 * hl_box_cols reads). */
__kernel void hl_box_rows(__global const float *restrict sums, __global float *restrict dst, const int ncw,
                          const int nch, const int oy, const int ox, __global const uchar *restrict cells)
{
    const int i = get_global_id(0), j = get_global_id(1), cplane = ncw * nch;
    if (!(cells[j * ncw + i] & HL_WORK_ROWS))
        return;
    const int i0 = max(i - HL_CELL_R, 0), i1 = min(i + HL_CELL_R, ncw - 1);
    for (int q = 0; q < HL_SUMS; q++)
        dst[q * cplane + j * ncw + i] = box_sum_rect(sums + q * cplane, ncw, i0, i1, j, j);
}

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

/* hl_box_cols: the box of (2 HL_CELL_R + 1)^2 cells around each cell (hl_box_rows' sums over
 * 2 HL_CELL_R + 1 rows), and from it what hl_apply needs per cell, HL_REFS planes of nch x ncw:
 * 0-2 the far references' chroma rho^ (chroma_of), 3 their agreement with the rim's (d the display
 * matrix), 4-5 their weight and weighted brightness (the box's sums 0 and 3), 6-8 the rim's
 * difference chroma along the surface's, Delta (highlights.rim_difference), 9-11 the surface's
 * chroma less 1, c, 12-14 g = d^T e / |e|^2 with e the part of d c across d (1, 1, 1) (0 where the
 * surface has no chroma: highlights.surface_projection's s is g . y), 15 (d c . d 1) / |d 1|^2,
 * 16 the largest output channel of d Delta, 17 |Delta|^2; at the cells with HL_WORK_BOX (where
 * hl_apply reads them). */
__kernel void hl_box_cols(__global const float *restrict rows, __global float *restrict dst, const int ncw,
                          const int nch, const int oy, const int ox, __global const uchar *restrict cells,
                          __constant const float *restrict d)
{
    const int i = get_global_id(0), j = get_global_id(1), cplane = ncw * nch;
    if (!(cells[j * ncw + i] & HL_WORK_BOX))
        return;
    const int j0 = max(j - HL_CELL_R, 0), j1 = min(j + HL_CELL_R, nch - 1);
    float s[HL_SUMS];
    for (int q = 0; q < HL_SUMS; q++)
        s[q] = box_sum_rect(rows + q * cplane, ncw, i, i, j0, j1);
    float far[3], rim[3], surface[3], c[3];
    chroma_of(s[0], s[1], s[2], far);
    chroma_of(s[4], s[5], s[6], rim);
    chroma_of(s[9], s[10], s[11], surface);
    for (int k = 0; k < 3; k++)
        c[k] = surface[k] - 1.0f;
    /* the rim's difference chroma along the surface's (highlights.rim_difference) */
    const float sw = s[4] + HL_PRIOR, delta[3] = {s[7] / sw, s[8] / sw, -(s[7] + s[8]) / sw};
    float dd = 0.0f, dc[3], d1[3], dl[3], a11 = 0.0f, a12 = 0.0f, a22 = 0.0f;
    for (int r = 0; r < 3; r++) {
        dl[r] = d[3 * r] * delta[0] + d[3 * r + 1] * delta[1] + d[3 * r + 2] * delta[2];
        dc[r] = d[3 * r] * c[0] + d[3 * r + 1] * c[1] + d[3 * r + 2] * c[2];
        d1[r] = d[3 * r] + d[3 * r + 1] + d[3 * r + 2];
        dd += dl[r] * dc[r];
        a11 += d1[r] * d1[r];
        a12 += dc[r] * d1[r];
        a22 += dc[r] * dc[r];
    }
    const float amount = a22 > 1e-12f ? hl_max(dd, 0.0f) / a22 : 0.0f;
    float e[3], ee = 0.0f, size = 0.0f, norm = 0.0f;       /* d c's part across d 1 */
    for (int r = 0; r < 3; r++) {
        e[r] = dc[r] - a12 / a11 * d1[r];
        ee += e[r] * e[r];
        size = hl_max(size, fabs(amount * dc[r]));
        norm += amount * c[r] * amount * c[r];
    }
    const int ok = a22 > 1e-12f && ee > 1e-6f * a22;
    const int at = j * ncw + i;
    dst[at] = far[0];
    dst[cplane + at] = far[1];
    dst[2 * cplane + at] = far[2];
    dst[3 * cplane + at] = agreement(far, rim, d);
    dst[4 * cplane + at] = s[0];
    dst[5 * cplane + at] = s[3];
    for (int k = 0; k < 3; k++) {
        dst[(6 + k) * cplane + at] = amount * c[k];
        dst[(9 + k) * cplane + at] = c[k];
        dst[(12 + k) * cplane + at] = ok ? (d[k] * e[0] + d[3 + k] * e[1] + d[6 + k] * e[2]) / ee : 0.0f;
    }
    dst[15 * cplane + at] = a12 / a11;
    dst[16 * cplane + at] = size;
    dst[17 * cplane + at] = norm;
}
#endif /* HL_RADIUS > 0 */

/* hl_apply (list: the cells within a cell of a flag): the rule of stage.py at output pixel (y, x)
 * = window pixel (y + RIM + R, x + RIM + R); the clipped channels from the flags (bit c) and the
 * soft test (a channel within HL_DIP of its threshold, clipped at one of the 8 neighbours, at a
 * pixel with another clipped channel: highlights.clipped_channels); wt: the free channels' weights;
 * h = d^T d (1, 1, 1) / |d (1, 1, 1)|^2 (surface_projection's white). HL_CLIP: clipped -> white n,
 * near -> neutral at the mean. Else the reconstruction: box: hl_box_cols' planes (ncw x nch
 * cells) at the pixel's cell; d the display matrix of agreement(). */
__kernel void hl_apply(__global const int *restrict list, __global const float *restrict src,
                       __global const uchar *restrict flags, __global const uchar *restrict nearby,
                       __global const float *restrict box, __global float *restrict dst,
                       const int width, const int height, const int w1, const int ncw, const int nch,
                       const int oy, const int ox, const int out_w, const int out_h,
                       __constant const float *restrict n, __constant const float *restrict t,
                       __constant const float *restrict d, __constant const float *restrict wt,
                       __constant const float *restrict h, const float white, const int wy, const int wx)
{
    const int2 q = list_pixel(list, wy, wx);
    const int x = q.x - HL_RIM - HL_RADIUS, y = q.y - HL_RIM - HL_RADIUS;
    if (x < 0 || y < 0 || x >= out_w || y >= out_h)
        return;
    const int plane = width * height, oplane = out_w * out_h;
    const int i = q.y * width + q.x;
    float v[3] = {src[i] / n[0], src[plane + i] / n[1], src[2 * plane + i] / n[2]};
    const int f = flags[i];
    int c0 = f & 1, c1 = (f >> 1) & 1, c2 = (f >> 2) & 1;
    if (f) {                                 /* soft: the channel clipped at a neighbour */
        int beside = 0;
        for (int dy = -1; dy <= 1; dy++)
            for (int dx = -1; dx <= 1; dx++)
                beside |= flags[i + dy * width + dx];
        c0 = c0 || ((beside & 1) && v[0] >= HL_DIP * t[0]);
        c1 = c1 || ((beside & 2) && v[1] >= HL_DIP * t[1]);
        c2 = c2 || ((beside & 4) && v[2] >= HL_DIP * t[2]);
    }
    const int count = c0 + c1 + c2;
    const uchar near = nearby[(y + HL_RADIUS) * w1 + x + HL_RADIUS];
    if (count == 0 && near == 0)
        return;                              /* unchanged: hl_copy has it */
#if HL_CLIP
    if (count > 0) {
        v[0] = v[1] = v[2] = white;
    } else if (near) {
        const float mean = (v[0] + v[1] + v[2]) / 3.0f;
        v[0] = v[1] = v[2] = mean;
    }
#else
    if (count == 3) {
        const float top = hl_max(hl_max(v[0], v[1]), v[2]);
        v[0] = v[1] = v[2] = top;
    } else {
        const int cell = ((y + HL_RADIUS + oy) / HL_CELL) * ncw + (x + HL_RADIUS + ox) / HL_CELL, cplane = ncw * nch;
        const float far[3] = {box[cell], box[cplane + cell], box[2 * cplane + cell]};
        const float s0 = box[4 * cplane + cell], s3 = box[5 * cplane + cell];
        const float delta[3] = {box[6 * cplane + cell], box[7 * cplane + cell], box[8 * cplane + cell]};
        const int clipped[3] = {c0, c1, c2};
        /* sat: a clipped channel whose record bounds the truth from below (reconstruct's saturated):
         * the record is itself a clipped value (at or above the clip threshold t / HL_MARGIN), or two
         * channels are clipped (one free channel cannot tell a colour) */
        int sat[3];
        for (int c = 0; c < 3; c++)
            sat[c] = clipped[c] && (v[c] >= t[c] / HL_MARGIN || count >= 2);
        /* trust in the far chroma (highlights.trust_in_far): agreement with the rim's (per cell) */
        float trust = box[3 * cplane + cell];
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
            const float rise = s0 > 0.0f ? implied * s0 / hl_max(s3, 1e-9f) : 0.0f;
            trust *= clamp((HL_RISE_HI - rise) / (HL_RISE_HI - HL_RISE_LO), 0.0f, 1.0f);
        }
        float rho[3];
        for (int c = 0; c < 3; c++)
            rho[c] = 1.0f + trust * (far[c] - 1.0f);
        if (count == 0) {                    /* rim: white plus the surface's colour (surface_projection) */
            const float mean = (v[0] + v[1] + v[2]) / 3.0f;
            float own[3];
            for (int c = 0; c < 3; c++)
                own[c] = mean > 0.0f ? v[c] / mean : 1.0f;
            const float keep = s0 / (s0 + HL_EVIDENCE) * (1.0f - agreement(own, far, d));
            /* white plus the surface's chroma c: s = g . v in [0, mean], b = h . v - (a12 / a11) s */
            const float c[3] = {box[9 * cplane + cell], box[10 * cplane + cell], box[11 * cplane + cell]};
            const float sp = clamp(box[12 * cplane + cell] * v[0] + box[13 * cplane + cell] * v[1] +
                                   box[14 * cplane + cell] * v[2], 0.0f, mean);
            const float b = h[0] * v[0] + h[1] * v[1] + h[2] * v[2] - box[15 * cplane + cell] * sp;
            for (int c2 = 0; c2 < 3; c2++)
                v[c2] += (1.0f - keep) * (b + sp * c[c2] - v[c2]);
        } else {
            float num = 0.0f, den = 0.0f, wsum = 0.0f;
            for (int c = 0; c < 3; c++)
                if (!clipped[c]) {
                    num += wt[c] * v[c];
                    den += wt[c] * rho[c];
                    wsum += wt[c];
                }
            float k = num / hl_max(den, 1e-6f);
            for (int c = 0; c < 3; c++)          /* a saturated record bounds the brightness below */
                if (sat[c] && rho[c] >= HL_RHO_MIN)
                    k = hl_max(k, v[c] / rho[c]);
            /* the additive estimate (highlights.additive_estimate): white b plus s of the rim's Delta */
            float pair = 0.0f, sfd = 0.0f, sfd2 = 0.0f, sfy = 0.0f, wy = 0.0f, wd = 0.0f;
            const float dd = box[17 * cplane + cell];
            for (int c = 0; c < 3; c++) {
                if (!clipped[c]) {
                    pair += v[c] * delta[c];
                    sfd += delta[c];
                    sfd2 += delta[c] * delta[c];
                    sfy += v[c];
                    wy += wt[c] * v[c];
                    wd += wt[c] * delta[c];
                }
            }
            const float prior = HL_ADD_PRIOR * dd;
            float sa = count == 1 ? clamp((2.0f * pair - sfy * sfd + prior) / hl_max(2.0f * sfd2 - sfd * sfd + prior, 1e-12f),
                                          0.0f, 1.0f) : 0.0f;
            const float wfree = hl_max(wsum, 1e-12f);
            const float b0 = hl_max((wy - sa * wd) / wfree, 0.0f);
            const float size = sa * box[16 * cplane + cell];
            if (size > HL_ADD_LIMIT * b0)
                sa *= HL_ADD_LIMIT * b0 / hl_max(size, 1e-12f);
            float b = (wy - sa * wd) / wfree;
            for (int c = 0; c < 3; c++)
                if (sat[c])
                    b = hl_max(b, v[c] - sa * delta[c]);
            for (int c = 0; c < 3; c++)
                if (clipped[c]) {
                    const float e = trust * k * rho[c] + (1.0f - trust) * (b + sa * delta[c]);
                    v[c] = sat[c] ? hl_max(v[c], e) : e;
                }
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
 * applies the 3 x 3 matrix m (the colour matrix and white balance pass 2 that follow, fused).
 * ENCODE_SRGB 1 (the tone curve fused too; the host then prepends clisp/modules/colour/srgb.h):
 * stores STORE's codes (store.h: QUANTIZE, CODE_BITS), H x W x 3 where INTERLEAVED. Halo 0. */
#include "store.h"
__kernel void hl_clamp(__global const float *restrict src, __global out_t *restrict dst, const int width,
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
    const float r = m[0] * a + m[1] * b + m[2] * c;
    const float g = m[3] * a + m[4] * b + m[5] * c;
    const float u = m[6] * a + m[7] * b + m[8] * c;
#else
    const float r = a, g = b, u = c;
#endif
#if INTERLEAVED
    dst[3 * i] = STORE(r);
    dst[3 * i + 1] = STORE(g);
    dst[3 * i + 2] = STORE(u);
#else
    dst[i] = STORE(r);
    dst[plane + i] = STORE(g);
    dst[2 * plane + i] = STORE(u);
#endif
}

/* hl_clamp8: hl_clamp for eight neighbouring pixels of a row per work-item, writing H x W x 3 (the
 * host's layout) through store_rgb8, for CPU devices: the clamp, the matrix and the tone curve in
 * one pass, where the curve's own kernel (srgb_encode8) read the planes again. Halo 0. Launched over
 * ceil(width / 8) x height work-items with a bounds check; the last of a row starts at width - 8
 * (it rewrites a few pixels with the same values), so width >= 8. */
__kernel void hl_clamp8(__global const float *restrict src, __global out_t *restrict dst, const int width,
                        const int height, const float cap0, const float cap1, const float cap2,
                        __constant const float *restrict m)
{
    const int gx = (int)get_global_id(0) * 8;
    const int y = get_global_id(1);
    if (gx >= width || y >= height) return;
    const int x = eight_from(gx, width);
    const int plane = width * height;
    const int i = y * width + x;
    const float8 a0 = *(__global const float8_u *)(src + i);
    const float8 b0 = *(__global const float8_u *)(src + plane + i);
    const float8 c0 = *(__global const float8_u *)(src + 2 * plane + i);
    const float8 a = a0 < cap0 ? a0 : (float8)(cap0), b = b0 < cap1 ? b0 : (float8)(cap1);
    const float8 c = c0 < cap2 ? c0 : (float8)(cap2);
#if MATRIX
    store_rgb8(dst + 3 * i, m[0] * a + m[1] * b + m[2] * c, m[3] * a + m[4] * b + m[5] * c,
               m[6] * a + m[7] * b + m[8] * c);
#else
    store_rgb8(dst + 3 * i, a, b, c);
#endif
}
