/* The statistics pass: the mosaic read once into the small tables every estimate of the scene
 * reads (clisp.scene.statistics; its NumPy definition is reference_statistics).
 *
 * Defines from the host: RAW_T (ushort or float, the raw's samples), ACC_T (long for integer raws,
 * whose sums and products are then exact; float otherwise), CFA_PERIOD, NCH (the CFA's channels),
 * BLOCK and CELL (px: the block table's blocks and the cells of its detail measure). */

#pragma OPENCL FP_CONTRACT OFF

#define CB (BLOCK / CELL)
#define NPROD (NCH * (NCH + 1) / 2)

/* stats_blocks: the block table. One work-item per BLOCK x BLOCK block (bx, by) of the W x H
 * mosaic (cols x rows blocks, the last ones partial), writing plane k of each output at
 * k * rows * cols + by * cols + bx:
 *   sums     (NCH planes) each channel's samples summed over the block's whole CELL x CELL cells;
 *   clipped  (NCH planes) each channel's samples at or above clip[c] (every sample of the block);
 *   uniform  1 when every CFA phase is constant in the block (each sample equals the one a period
 *            to its right and below it, inside the block), else 0;
 *   lap      (NPROD planes, i <= j in row-major order) the sum over the block's Laplacian positions
 *            of L_i L_j, L_c the 4-neighbour Laplacian of channel c's cell sums: centres on the cell
 *            rows 1 .. n - 2 of the block's n whole cell rows (the Laplacian reads no cell of the
 *            block rows above or below) and on the cell columns j of cx0 + 1 .. cx0 + CB (j <= wc - 2),
 *            the block of column j - 1.
 * Halo: one cell column right of the block (the last Laplacian's neighbour), inside the image.
 * The cell sums of three cell rows are kept in a ring as the rows are read, so each sample is read
 * once for the sums and the Laplacians (and once more, with its neighbours, for clipped and uniform). */
__kernel void stats_blocks(__global const RAW_T *restrict raw, const int width, const int height,
                           const int cols, const int rows, __constant const char *restrict pattern,
                           __constant const float *restrict clip, __global ACC_T *restrict sums,
                           __global int *restrict clipped, __global int *restrict uniform,
                           __global ACC_T *restrict lap)
{
    const int bx = get_global_id(0);
    const int by = get_global_id(1);
    const int nb = rows * cols;
    const int b = by * cols + bx;
    const int y0 = by * BLOCK, x0 = bx * BLOCK;
    const int y1 = min(y0 + BLOCK, height), x1 = min(x0 + BLOCK, width);

    int count[NCH];
    for (int c = 0; c < NCH; c++)
        count[c] = 0;
    int same = 1;
    for (int y = y0; y < y1; y++) {
        const __global RAW_T *row = raw + (size_t)y * width;
        for (int x = x0; x < x1; x++) {
            const RAW_T v = row[x];
            count[cfa_channel(pattern, y, x)] += (float)v >= clip[cfa_channel(pattern, y, x)];
            if (x + CFA_PERIOD < x1 && row[x + CFA_PERIOD] != v)
                same = 0;
            if (y + CFA_PERIOD < y1 && row[x + CFA_PERIOD * width] != v)
                same = 0;
        }
    }
    for (int c = 0; c < NCH; c++)
        clipped[c * nb + b] = count[c];
    uniform[b] = same;

    const int wc = width / CELL;
    const int cy0 = by * CB, cx0 = bx * CB;
    const int ncy = clamp(height / CELL - cy0, 0, CB);
    const int ncx = clamp(wc - cx0, 0, CB);
    const int last = min(cx0 + CB + 1, wc - 1);          /* the last cell column read */
    const int j1 = min(cx0 + CB, wc - 2);                /* the last Laplacian centre column */
    ACC_T total[NCH], prod[NPROD];
    ACC_T ring[3][CB + 2][NCH];                          /* cell sums of columns cx0 .. cx0 + CB + 1 */
    for (int c = 0; c < NCH; c++)
        total[c] = 0;
    for (int k = 0; k < NPROD; k++)
        prod[k] = 0;
    for (int i = 0; i < ncy; i++) {
        const int slot = i % 3;
        const int cy = (cy0 + i) * CELL;
        for (int col = cx0; col <= last; col++) {
            ACC_T s[NCH];
            for (int c = 0; c < NCH; c++)
                s[c] = 0;
            for (int py = 0; py < CELL; py++) {
                const __global RAW_T *row = raw + (size_t)(cy + py) * width + col * CELL;
                for (int px = 0; px < CELL; px++)
                    s[pattern[(py % CFA_PERIOD) * CFA_PERIOD + px % CFA_PERIOD]] += (ACC_T)row[px];
            }
            for (int c = 0; c < NCH; c++) {
                ring[slot][col - cx0][c] = s[c];
                if (col - cx0 < ncx)
                    total[c] += s[c];
            }
        }
        if (i < 2)
            continue;
        const int up = (i - 2) % 3, mid = (i - 1) % 3;
        for (int j = cx0 + 1; j <= j1; j++) {
            const int k = j - cx0;
            ACC_T l[NCH];
            for (int c = 0; c < NCH; c++)
                l[c] = ring[up][k][c] + ring[slot][k][c] + ring[mid][k - 1][c] + ring[mid][k + 1][c]
                       - 4 * ring[mid][k][c];
            int n = 0;
            for (int a = 0; a < NCH; a++)
                for (int c = a; c < NCH; c++)
                    prod[n++] += l[a] * l[c];
        }
    }
    for (int c = 0; c < NCH; c++)
        sums[c * nb + b] = total[c];
    for (int k = 0; k < NPROD; k++)
        lap[k * nb + b] = prod[k];
}

/* stats_cells: the cell thumbnail. One work-item per thumbnail cell (tx, ty) of tw x th: the CFA
 * cell (period x period px) at (ty stride p, tx stride p); writes each channel's mean normalised
 * sample ((raw - black[c]) scale[c], float32, summed in row-major order and divided by the
 * channel's samples per cell, counts[c]) to cells[(ty tw + tx) NCH + c] and whether a normalised
 * sample is at or above clip_fraction to clipped[ty tw + tx]. Halo 0. */
__kernel void stats_cells(__global const RAW_T *restrict raw, const int width, const int stride,
                          const int tw, const int th, __constant const char *restrict pattern,
                          __constant const float *restrict black, __constant const float *restrict scale,
                          __constant const float *restrict counts, const float clip_fraction,
                          __global float *restrict cells, __global uchar *restrict clipped)
{
    const int tx = get_global_id(0);
    const int ty = get_global_id(1);
    const int y0 = ty * stride * CFA_PERIOD, x0 = tx * stride * CFA_PERIOD;
    float acc[NCH];
    for (int c = 0; c < NCH; c++)
        acc[c] = 0.0f;
    int hit = 0;
    for (int dy = 0; dy < CFA_PERIOD; dy++)
        for (int dx = 0; dx < CFA_PERIOD; dx++) {
            const int c = pattern[dy * CFA_PERIOD + dx];
            const float v = ((float)raw[(size_t)(y0 + dy) * width + x0 + dx] - black[c]) * scale[c];
            hit |= v >= clip_fraction;
            acc[c] += v;
        }
    const int t = ty * tw + tx;
    for (int c = 0; c < NCH; c++)
        cells[t * NCH + c] = acc[c] / counts[c];
    clipped[t] = (uchar)hit;
}
