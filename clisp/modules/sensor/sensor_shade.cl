/* The smooth gain of the sensor corrections after the chroma stage (clisp/modules/sensor/stage.py,
 * SensorShade). No defines. */

#include "sensor.h"

/* sensor_shade: the smooth gain G on the chroma stage's output, in camera space: out = M diag(G(p))
 * M^-1 in, M the colour matrix (linear sRGB here; the identity on camera channels). G_c per
 * channel from the grid (as sensor_correct divides it out), at image pixel (y + oy, x + ox) times
 * ``scale`` (2 after the half-size binning). Halo 0. src, dst: 3 planes of width x height. */
__kernel void sensor_shade(__global const float *restrict src, __global float *restrict dst,
                           const int width, const int height, const int oy, const int ox, const float scale,
                           __constant const float *restrict m, __constant const float *restrict m_inv,
                           __global const float *restrict grid, const int gh, const int gw, const float inv_cell)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    const int plane = width * height, i = y * width + x;
    const float iy = ((float)(y + oy) + 0.5f) * scale - 0.5f, ix = ((float)(x + ox) + 0.5f) * scale - 0.5f;
    const float a = src[i], b = src[plane + i], d = src[2 * plane + i];
    float cam[3];
    for (int c = 0; c < 3; c++)
        cam[c] = (m_inv[3 * c] * a + m_inv[3 * c + 1] * b + m_inv[3 * c + 2] * d)
                 * grid_gain(grid, gh, gw, inv_cell, c, iy, ix);
    for (int c = 0; c < 3; c++)
        dst[c * plane + i] = m[3 * c] * cam[0] + m[3 * c + 1] * cam[1] + m[3 * c + 2] * cam[2];
}
