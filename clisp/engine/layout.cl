/* Memory-layout steps between the device's planar images and the host's interleaved arrays. */

/* interleave: planar NCH x H x W -> interleaved H x W x NCH, so the host receives its array layout
 * in one contiguous download. Halo 0. NCH (define): number of planes. */
__kernel void interleave(__global const float *restrict src, __global float *restrict dst, const int width, const int height)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= width || y >= height) return;
    const int i = y * width + x;
    const int plane = width * height;
    for (int c = 0; c < NCH; ++c)
        dst[i * NCH + c] = src[c * plane + i];
}
