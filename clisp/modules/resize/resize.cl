/* Separable resampling (clisp/modules/resize/stage.py: the step list, the tap tables and the NumPy
 * reference, resize_reference). An output pixel is a normalised weighted sum of `taps` input
 * pixels along one axis, starting at `starts[i]`, weights `weights[i * taps + k]`; the host
 * computes both tables (a Lanczos-3 kernel stretched by the scale factor, so the cutoff is the
 * output's Nyquist; weights normalised to sum 1, zero past the kernel's support and past the image
 * edges). No constant lives here: tap counts, strides and offsets are arguments; INTERLEAVED
 * (define) picks the vertical pass's output layout.
 *
 * Launched over exactly their outputs (launch_exact): no bounds checks, which would stop PoCL
 * vectorising. Sums run k = 0 .. taps-1 in order, so an output pixel does not depend on which
 * launch computed it (tiled equals whole, bit for bit). */

/* resize_rows: the horizontal pass. src: interleaved host rows (H x W x 3 float), row r of this
 * launch at src + (src_row0 + r) * src_stride, its column 0 at image column src_x0 (a crop);
 * dst: the window, rows of 3 planes [row][channel][x] of dst_width floats, this launch's row r
 * written at window row dst_row0 + r. One work-item per output column x and row r. */
__kernel void resize_rows(__global const float *restrict src, __global float *restrict dst,
                          __global const int *restrict starts, __global const float *restrict weights,
                          const int taps, const int src_stride, const int src_x0, const int src_row0,
                          const int dst_width, const int dst_row0)
{
    const int x = get_global_id(0);
    const int r = get_global_id(1);
    __global const float *p = src + (src_row0 + r) * src_stride + 3 * (src_x0 + starts[x]);
    __global const float *w = weights + x * taps;
    float red = 0.0f, green = 0.0f, blue = 0.0f;
    for (int k = 0; k < taps; ++k) {
        const float wk = w[k];
        red += wk * p[3 * k];
        green += wk * p[3 * k + 1];
        blue += wk * p[3 * k + 2];
    }
    __global float *row = dst + (dst_row0 + r) * 3 * dst_width + x;
    row[0] = red;
    row[dst_width] = green;
    row[2 * dst_width] = blue;
}

/* resize_columns: the vertical pass. window: rows of 3 planes of `width` floats (resize_rows'
 * output), whose row 0 is the image's (cropped) row window_row0; output row j = out_row0 + r reads
 * image rows starts[j] .. starts[j] + taps - 1. dst: rows out_row0 .. out_row0 + out_rows - 1 as 3
 * planes of out_rows x width (INTERLEAVED 0: what the tone curve reads), or out_rows x width x 3
 * (INTERLEAVED 1: the host layout, for linear outputs). One work-item per column x and row r. */
__kernel void resize_columns(__global const float *restrict window, __global float *restrict dst,
                             __global const int *restrict starts, __global const float *restrict weights,
                             const int taps, const int width, const int window_row0, const int out_row0,
                             const int out_rows)
{
    const int x = get_global_id(0);
    const int r = get_global_id(1);
    const int j = out_row0 + r;
    __global const float *p = window + (starts[j] - window_row0) * 3 * width + x;
    __global const float *w = weights + j * taps;
    float red = 0.0f, green = 0.0f, blue = 0.0f;
    for (int k = 0; k < taps; ++k) {
        const float wk = w[k];
        __global const float *q = p + k * 3 * width;
        red += wk * q[0];
        green += wk * q[width];
        blue += wk * q[2 * width];
    }
#if INTERLEAVED
    __global float *out = dst + 3 * (r * width + x);
    out[0] = red;
    out[1] = green;
    out[2] = blue;
#else
    const int plane = out_rows * width;
    dst[r * width + x] = red;
    dst[plane + r * width + x] = green;
    dst[2 * plane + r * width + x] = blue;
#endif
}
