/* Per-pixel colour steps on planar 3-channel images. Launched over exactly width x height
 * (launch_exact): no bounds checks, which would stop PoCL vectorising. */

/* apply_matrix3: dst_i = sum_j m[3 i + j] * src_j. Halo 0. Colour conversion (camera -> linear
 * sRGB) and white balance pass 2 (a diagonal matrix) are both this kernel. */
__kernel void apply_matrix3(__global const float *restrict src, __global float *restrict dst,
                            const int width, const int height, __constant const float *restrict m)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int plane = width * height;
    const int i = y * width + x;
    const float a = src[i], b = src[plane + i], c = src[2 * plane + i];
    dst[i]             = m[0] * a + m[1] * b + m[2] * c;
    dst[plane + i]     = m[3] * a + m[4] * b + m[5] * c;
    dst[2 * plane + i] = m[6] * a + m[7] * b + m[8] * c;
}

/* srgb_encode: clip to [0, 1] and sRGB-encode (encode_srgb, clisp/modules/colour/srgb.h, prepended by the host)
 * the 3 planes of a linear image. Halo 0. QUANTIZE (define): 1 writes codes of CODE_BITS (define:
 * 16, ushort, or 8, uchar), 0 float. INTERLEAVED (define): 1 writes H x W x 3 (the host layout), 0 three planes. */
#ifdef SRGB_M0
#define ENCODE_SRGB 1                /* store.h's out_t and STORE: encoded, as codes where QUANTIZE */
#include "store.h"
__kernel void srgb_encode(__global const float *restrict src, __global out_t *restrict dst, const int width, const int height)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int plane = width * height;
    const int i = y * width + x;
    const out_t r = STORE(src[i]);             /* written out per channel: a loop over */
    const out_t g = STORE(src[plane + i]);     /* the planes ran 2.5x slower on PoCL */
    const out_t b = STORE(src[2 * plane + i]);
#if INTERLEAVED
    dst[3 * i] = r;
    dst[3 * i + 1] = g;
    dst[3 * i + 2] = b;
#else
    dst[i] = r;
    dst[plane + i] = g;
    dst[2 * plane + i] = b;
#endif
}

/* srgb_encode8: srgb_encode writing H x W x 3 (the host layout), eight pixels per work-item: their
 * 24 values stored as three consecutive vectors (the scalar kernel's interleaved stores become
 * scattered scalar stores on PoCL: 16-bit codes of 24 MP at 177 MP/s interleaved against 500
 * planar). Halo 0. Launched over ceil(width / 8) x height work-items with a bounds check; the last
 * work-item of a row starts at width - 8 (it rewrites a few pixels with the same values), so
 * width >= 8. QUANTIZE as srgb_encode. */
__kernel void srgb_encode8(__global const float *restrict src, __global out_t *restrict dst, const int width, const int height)
{
    const int gx = (int)get_global_id(0) * 8;
    const int y = get_global_id(1);
    if (gx >= width || y >= height) return;
    const int x = eight_from(gx, width);
    const int plane = width * height;
    const int i = y * width + x;
    store_rgb8(dst + 3 * i, *(__global const float8_u *)(src + i), *(__global const float8_u *)(src + plane + i),
               *(__global const float8_u *)(src + 2 * plane + i));
}
#endif
