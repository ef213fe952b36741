/* Per-pixel colour steps on planar 3-channel images. */

/* apply_matrix3: dst_i = sum_j m[3 i + j] * src_j. Halo 0. Colour conversion (camera -> linear
 * sRGB) and white balance pass 2 (a diagonal matrix) are both this kernel. */
__kernel void apply_matrix3(__global const float *src, __global float *dst,
                            const int width, const int height, __constant const float *m)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= width || y >= height) return;
    const int plane = width * height;
    const int i = y * width + x;
    const float a = src[i], b = src[plane + i], c = src[2 * plane + i];
    dst[i]             = m[0] * a + m[1] * b + m[2] * c;
    dst[plane + i]     = m[3] * a + m[4] * b + m[5] * c;
    dst[2 * plane + i] = m[6] * a + m[7] * b + m[8] * c;
}

/* srgb_encode: clip to [0, 1], then the IEC 61966-2-1 transfer function. Halo 0.
 * Planes are stacked, so height = 3 H. SRGB_* constants come from the host (clisp.colorimetry). */
__kernel void srgb_encode(__global const float *src, __global float *dst,
                          const int width, const int height)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= width || y >= height) return;
    const int i = y * width + x;
    const float v = clamp(src[i], 0.0f, 1.0f);
    dst[i] = (v <= SRGB_THRESHOLD) ? SRGB_SLOPE * v
                                   : SRGB_SCALE * pow(v, SRGB_INV_GAMMA) - SRGB_OFFSET;
}
