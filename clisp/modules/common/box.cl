/* The one device box filter: window sums (or means) over 2R + 1 consecutive pixels along x or y, of
 * every plane of a planar float32 image (plane p of an h x w image starts at element p h w). Host side
 * and NumPy reference: clisp/modules/common/box.py (enqueue_box, box_sums). A 2-D box is box_rows then
 * box_cols (the sums are separable; rows first, as every caller's reference sums).
 *
 * Defines from the host: BOX_R, the radius R (compile-time, so the loop unrolls fully and PoCL
 * vectorises the kernel across work-items).
 * Tiling convention: valid-only windows, the output shrinks by 2R along the filtered axis; no bounds
 * checks (the host launches the outputs in one command, runtime.launch_exact with inward=True). The sum runs k = 0 .. 2R in
 * order, from 0.0f, then is multiplied by ``scale`` (1: sums; 1 / (2R + 1)^2 on the second pass: a
 * 2-D mean), so a caller's results do not depend on which stage launched it. The sums themselves are
 * box.h's, which kernels that need box sums at their own sites include too. */

#include "box.h"

/* box_rows: dst(p, y, x) = scale * sum_{k=0..2R} src(p, y, x + k). Planes are stacked along y: launch
 * out_w x (planes * h) = out_w x rows. Output x is input column x + R. Halo R along x. */
__kernel void box_rows(__global const float *restrict src, __global float *restrict dst, const int in_w,
                       const int out_w, const float scale, const int rows)
{
    const int x = inward_id(0, out_w - 1);                 /* one command: common.h */
    const int y = inward_id(1, rows - 1);
    dst[y * out_w + x] = box_sum(src + y * in_w + x, 1) * scale;
}

/* box_cols: dst(p, y, x) = scale * sum_{k=0..2R} src(p, y + k, x), every plane: launch w x
 * (planes * out_h) = w x rows, the plane being gid1 / out_h. Output y is input row y + R. Halo R along y. */
__kernel void box_cols(__global const float *restrict src, __global float *restrict dst, const int w,
                       const int in_h, const int out_h, const float scale, const int rows)
{
    const int x = inward_id(0, w - 1);                     /* one command: common.h */
    const int g = inward_id(1, rows - 1);
    const int p = g / out_h, y = g - p * out_h;
    dst[g * w + x] = box_sum(src + (p * in_h + y) * w + x, w) * scale;
}
