/* Flat-tile demosaic (clisp/modules/demosaic_flat/stage.py): per-channel box means on a grid of cells,
 * interpolated bilinearly, plus the neutral luminance residual of a 3 x 3 kernel.
 * Defines from the host: CFA_PERIOD (P), CELL (cell side, a multiple of P), CELLS (Rc, box radius
 * in cells), NCH (channels). Cell grids are planar (NCH planes). Steps: flat_cells -> flat_reflect (tiles
 * at the image's edge) -> the box means of the cells (the shared box filter, clisp/modules/common/box.cl,
 * radius Rc cells, scale 1 / (2 Rc + 1)^2) -> flat_rows -> flat_output. */

/* flat_cells: cells (NCH planes of cy x cx) = mean of each channel's samples in the CELL x CELL
 * cell whose first pixel is window pixel (ay + CELL i, ax + CELL j); (ay, ax) is a multiple of CELL
 * in image coordinates, so the cell's pixel (py, px) has channel pattern[py][px] (the CFA pattern
 * tiled to CELL x CELL). inv_count[c] = 1 / sites of c per cell. Halo 0 (a CELL-fold reduction).
 * Launched over exactly cx x cy. */
__kernel void flat_cells(__global const float *restrict src, __global float *restrict cells,
                         const int width, const int ay, const int ax, const int cx, const int cy,
                         __constant const char *restrict pattern, __constant const float *restrict inv_count)
{
    const int j = get_global_id(0);
    const int i = get_global_id(1);
    const __global float *p = src + (ay + CELL * i) * width + ax + CELL * j;
    float acc[NCH];
    for (int c = 0; c < NCH; c++)
        acc[c] = 0.0f;
    for (int py = 0; py < CELL; py++)
        for (int px = 0; px < CELL; px++) {
            const int ch = pattern[py * CELL + px];
            const float v = p[py * width + px];
            for (int c = 0; c < NCH; c++)
                acc[c] += ch == c ? v : 0.0f;
        }
    for (int c = 0; c < NCH; c++)
        cells[(c * cy + i) * cx + j] = acc[c] * inv_count[c];
}

/* reflect_term: term t of demosaic_flat.reflect_terms for index i about [first, last] with anchor
 * K: inside, one term (i, 1); outside, 2K + 2 terms: cells c - K .. c + K with 2 / (2K + 1), then
 * (2c - i clamped to first .. last, -1), c = first + K (or last - K). Returns the index, sets *w. */
inline int reflect_term(const int i, const int first, const int last, const int k, const int t, float *w)
{
    if (i >= first && i <= last) {
        *w = 1.0f;
        return i;
    }
    const int c = i < first ? first + k : last - k;
    if (t <= 2 * k) {
        *w = 2.0f / (2 * k + 1);
        return c - k + t;
    }
    *w = -1.0f;
    return clamp(2 * c - i, first, last);             /* a narrow window holds no cell beyond */
}

/* flat_reflect: dst = cells with every cell outside rows i0..i1 or columns j0..j1 (past the
 * image's edges) replaced by the point reflection about the mean of the 2K + 1 edge cells,
 * separably along y (anchor ky) and x (kx): demosaic_flat.reflect_cells. Launched over exactly
 * cx x cy. */
__kernel void flat_reflect(__global const float *restrict cells, __global float *restrict dst,
                           const int cx, const int cy, const int i0, const int i1, const int j0, const int j1,
                           const int ky, const int kx)
{
    const int j = get_global_id(0);
    const int i = get_global_id(1);
    const int ny = (i >= i0 && i <= i1) ? 1 : 2 * ky + 2;
    const int nx = (j >= j0 && j <= j1) ? 1 : 2 * kx + 2;
    for (int c = 0; c < NCH; c++) {
        const __global float *p = cells + c * cy * cx;
        float v = 0.0f;
        for (int ty = 0; ty < ny; ty++) {
            float wy;
            const int iy = reflect_term(i, i0, i1, ky, ty, &wy);
            for (int tx = 0; tx < nx; tx++) {
                float wx;
                const int jx = reflect_term(j, j0, j1, kx, tx, &wx);
                v += wy * wx * p[iy * cx + jx];
            }
        }
        dst[(c * cy + i) * cx + j] = v;
    }
}

/* flat_rows: rows (NCH planes of oh x bw) = the box means interpolated along y at each output row:
 * rows_c(y, j) = (1 - fy) box_c(iy, j) + fy box_c(iy + 1, j), iy + fy = uy = (Y - ay - centroid_c) / CELL - Rc,
 * Y = y + halo (box cell i is centred on cell i + Rc, and a cell's mean of channel c sits at the
 * centroid of c's sites in it: centroid = (row, column) per channel). The first half of the
 * bilinear interpolation, once per row and box column instead of once per output pixel. Launched
 * over exactly bw x oh. */
__kernel void flat_rows(__global const float *restrict box, __global float *restrict rows, const int bw,
                        const int bh, const int oh, const int halo, const int ay,
                        __constant const float *restrict centroid)
{
    const int j = get_global_id(0);
    const int y = get_global_id(1);
    for (int c = 0; c < NCH; c++) {
        const float uy = ((float)(y + halo - ay) - centroid[2 * c]) * (1.0f / CELL) - CELLS;
        const int iy = (int)floor(uy);
        const float fy = uy - iy;
        const __global float *q = box + (c * bh + iy) * bw + j;
        rows[(c * oh + y) * bw + j] = (1.0f - fy) * q[0] + fy * q[bw];
    }
}

/* flat_output: dst (NCH planes of oh x ow); one work-item computes the CELL output pixels
 * x = CELL q + s, s = 0 .. CELL - 1, of row y. Output pixel (y, x) is window pixel (Y, X) =
 * (y + halo, x + halo); (ax) the window column of the first cell, (oy, ox) the image coordinate of
 * window pixel (0, 0). mean_c = rows_c (flat_rows) interpolated along x at
 * u = (X - ax - centroid_c) / CELL - Rc = q + k_sc + f_sc: since halo, ax and CELL q are fixed
 * modulo CELL, the offset k_sc and weight f_sc depend on s and c alone (computed once, here, the
 * same for every work-item), so neighbouring work-items read neighbouring cells; the CFA phase
 * likewise (P divides CELL). d = a . x(3 x 3 around (Y, X), row-major) - b . mean: the 3 x 3
 * residual kernel's normalised weights for the pixel's CFA phase (DemosaicFlat.residual_tables:
 * a (P*P, 9), b (P*P, NCH)). out_c = mean_c + d. Halo (Rc + 2) CELL. Launched over exactly
 * ceil(ow / CELL) x oh; the last work-item of a row writes only the pixels inside ow. A pixel in
 * a block that nobody reads (unread[by * unread_w + bx] != 0, blocks of `block` px on the image's
 * multiples of `block`; unread_h 0: none) is written 0 instead. */
__kernel void flat_output(__global const float *restrict src, __global const float *restrict rows,
                          __global float *restrict dst, const int width, const int bw,
                          const int ow, const int oh, const int halo, const int ax,
                          const int oy, const int ox, __constant const float *restrict a,
                          __constant const float *restrict b, __constant const float *restrict centroid,
                          __global const uchar *restrict unread, const int unread_w, const int unread_h,
                          const int block)
{
    const int q = get_global_id(0);
    const int y = get_global_id(1);
    const int Y = y + halo;
    const int py = (Y + oy) & (CFA_PERIOD - 1);       /* P is 2 or 4: & is the modulo, also below 0 */
    for (int s = 0; s < CELL; s++) {
        const int x = CELL * q + s;
        if (x >= ow)
            return;
        const int X = x + halo;
        const int o = y * ow + x;
        const int gy = Y + oy, gx = X + ox;           /* image coordinates */
        if (unread_h > 0 && gy >= 0 && gx >= 0 && gy < unread_h * block && gx < unread_w * block
            && unread[(gy / block) * unread_w + gx / block]) {
            for (int c = 0; c < NCH; c++)
                dst[c * oh * ow + o] = 0.0f;
            continue;
        }
        float m[NCH];
        for (int c = 0; c < NCH; c++) {
            const float u0 = ((float)(halo + s - ax) - centroid[2 * c + 1]) * (1.0f / CELL) - CELLS;
            const int k = (int)floor(u0);
            const float fx = u0 - k;
            const __global float *r = rows + (c * oh + y) * bw + q + k;
            m[c] = (1.0f - fx) * r[0] + fx * r[1];
        }
        const int px = (X + ox) & (CFA_PERIOD - 1);
        __constant const float *ap = a + (py * CFA_PERIOD + px) * 9;
        __constant const float *bp = b + (py * CFA_PERIOD + px) * NCH;
        const __global float *p = src + (Y - 1) * width + X - 1;
        float d = 0.0f;
        for (int dy = 0; dy < 3; dy++)
            for (int dx = 0; dx < 3; dx++)
                d += ap[3 * dy + dx] * p[dy * width + dx];
        for (int c = 0; c < NCH; c++)
            d -= bp[c] * m[c];
        for (int c = 0; c < NCH; c++)
            dst[c * oh * ow + o] = m[c] + d;
    }
}
