/* Per-pixel steps on the raw mosaic (before demosaic). */

/* RAW_T (define from the host): the input sample type, ushort for quantised raws, float otherwise. */

/* cfa_affine: dst = (src - offset[c]) * scale[c], c the CFA channel of the pixel. Halo 0.
 * Black/white normalisation (offset = black, scale = 1/(white - black)) and white balance
 * pass 1 (offset 0, scale = gain) are both this kernel. (oy, ox) = image coordinate of pixel 0.
 * Launched over exactly width x height (launch_exact): no bounds check, so PoCL vectorises it. */
__kernel void cfa_affine(__global const RAW_T *restrict src, __global float *restrict dst,
                         const int width, const int height, const int oy, const int ox,
                         __constant const char *restrict pattern,
                         __constant const float *restrict offset, __constant const float *restrict scale)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int c = cfa_channel(pattern, y + oy, x + ox);
    const int i = y * width + x;
    dst[i] = ((float)src[i] - offset[c]) * scale[c];
}
