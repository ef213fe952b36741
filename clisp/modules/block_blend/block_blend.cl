/* Block blend: the detail path's output joined to the flat path's inside one tile (clisp.skip's
 * "mixed" tiles); NumPy reference and the rule in clisp/modules/block_blend/blend.py, one kernel,
 * same name.
 *
 * blend_detail: for output pixel (y, x) of a rectangle of the tile (image coordinates
 * (gy, gx) = (rect_y + y, rect_x + x)), d = the Chebyshev distance in px from (gy, gx) to the
 * nearest texture block (mask[by * mask_w + bx] != 0: blocks of `block` px on image multiples of
 * `block`), looked for among the (2 reach_blocks + 1)^2 blocks around the pixel's own (0 without
 * looking inside a texture block);
 * w = clamp((reach + ramp - d) / ramp, 0, 1); then, in each of the 3 planes,
 * flat(rect + (y, x)) <- w >= 1: detail(y, x); w <= 0: kept; else flat + w (detail - flat).
 * flat: the tile's 3 planes (tile_w wide, tile_h high); detail: the rectangle's 3 planes
 * (out_w x out_h); (off_y, off_x): the rectangle's origin in the tile. Halo 0. It writes in place,
 * so each pixel must be joined once: launched over the output rounded up to work-groups, with a
 * bounds check (launch_exact's shifted ragged strips would join some pixels twice). */
__kernel void blend_detail(__global float *restrict flat, __global const float *restrict detail,
                           __global const uchar *restrict mask, const int tile_w, const int tile_h,
                           const int out_w, const int out_h, const int off_y, const int off_x,
                           const int rect_y, const int rect_x, const int mask_w, const int mask_h,
                           const int block, const int reach_blocks, const float reach, const float ramp)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= out_w || y >= out_h)
        return;
    const int gy = rect_y + y, gx = rect_x + x;
    const int by = gy / block, bx = gx / block;
    float d = mask[by * mask_w + bx] ? 0.0f : reach + ramp;      /* inside a texture block: w = 1 */
    for (int j = d > 0.0f ? max(by - reach_blocks, 0) : mask_h; j <= min(by + reach_blocks, mask_h - 1); ++j) {
        const int dy = max(max(j * block - gy, gy - (j * block + block - 1)), 0);
        for (int i = max(bx - reach_blocks, 0); i <= min(bx + reach_blocks, mask_w - 1); ++i) {
            if (mask[j * mask_w + i]) {
                const int dx = max(max(i * block - gx, gx - (i * block + block - 1)), 0);
                d = fmin(d, (float)max(dy, dx));
            }
        }
    }
    const float w = clamp((reach + ramp - d) / ramp, 0.0f, 1.0f);
    if (w <= 0.0f)
        return;
    const int plane_t = tile_w * tile_h, plane_r = out_w * out_h;
    const int t = (off_y + y) * tile_w + off_x + x, r = y * out_w + x;
    for (int c = 0; c < 3; ++c) {
        const float f = flat[c * plane_t + t], v = detail[c * plane_r + r];
        flat[c * plane_t + t] = w >= 1.0f ? v : f + w * (v - f);
    }
}
