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
 * the 3 planes of a linear image. Halo 0. QUANTIZE (define): 1 writes 16-bit codes (ushort),
 * 0 float. INTERLEAVED (define): 1 writes H x W x 3 (the host layout), 0 three planes. */
#ifdef SRGB_M0
#if QUANTIZE
typedef ushort out_t;
#define STORE(v) quantize16(v)
#else
typedef float out_t;
#define STORE(v) (v)
#endif
__kernel void srgb_encode(__global const float *restrict src, __global out_t *restrict dst, const int width, const int height)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int plane = width * height;
    const int i = y * width + x;
    const out_t r = STORE(encode_srgb(src[i]));             /* written out per channel: a loop over */
    const out_t g = STORE(encode_srgb(src[plane + i]));     /* the planes ran 2.5x slower on PoCL */
    const out_t b = STORE(encode_srgb(src[2 * plane + i]));
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
#endif
