/* Building blocks of the masked guided filter of the residual-interpolation Bayer demosaics (RI, MLRI,
 * ARI; NumPy float64 reference: clisp/stages/bayer_ri.py, guided_filter / WindowStats / _fit). Host side:
 * clisp/stages/guided_ri.py. Windows are ("box", ry, rx) rectangles, (2ry+1) x (2rx+1) pixels.
 *
 * Run in this order for one filter of target y against guide x over the mask m (all H x W):
 *   gf_products (6 planes: m, m x, m y, m x^2, m y^2, m x y)     halo 0
 *   box_x(rx), box_y(ry) of the 6 planes                         halo rx along x, ry along y
 *   gf_coefficients (a, b; weighted: a w, b w, w)                halo 0
 *   box_x(rx), box_y(ry) of those planes                         halo rx, ry
 *   gf_apply (q = (sum a) x + sum b, over the count or sum w)    halo 0
 * Total halo 2ry along y, 2rx along x: an H x W window gives its (H - 4ry) x (W - 4rx) interior.
 *
 * Tiling convention: every kernel reads a window already padded by its halo and writes the interior;
 * images are planar float32 (plane p of an h x w image starts at p h w); no bounds checks (the host
 * launches exactly the outputs, runtime.launch_exact). Units are the caller's (ARI: 8-bit, 0..255).
 * Statistics are plain (uncentred) sums in float32: var = E[x^2] - E[x]^2 loses ~1e-7 E[x^2] to
 * cancellation (~4e-3 at 255), so a window whose guide variance is below that (flat areas) gets an
 * ill-conditioned slope a, as the float64 reference does below its own ~1e-11 (eps is 1e-10).
 *
 * Defines from the host: GF_MASKED (1: statistics over the mask plane; 0: every pixel, no mask read),
 * GF_WEIGHTED (1: ARI's 1 / RMSE weighted means of a, b; 0: plain window means). */

#ifndef GF_MASKED
#define GF_MASKED 1
#endif
#ifndef GF_WEIGHTED
#define GF_WEIGHTED 0
#endif
#define GF_MIN_COUNT 1.0f      /* n = max(box(m), 1): an empty window gives a = 0, b = 0 (reference) */
#define GF_RMSE_FLOOR 1e-3f    /* weight = 1 / max(RMSE, 1e-3) (ARI, 8-bit units) */
#define GF_WEIGHT_REG 1e-4f    /* total weight + 1e-4 */

/* box_x: dst(p, y, x) = sum_{k=0..2r} src(p, y, x + k), every plane (planes stacked along y: launch
 * out_w x planes * h). Output x is input column x + r: width shrinks by 2r. Halo r along x. */
__kernel void box_x(__global const float *restrict src, __global float *restrict dst, const int r,
                    const int in_w, const int out_w)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    __global const float *s = src + y * in_w + x;
    float acc = 0.0f;
    for (int k = 0; k <= 2 * r; ++k)
        acc += s[k];
    dst[y * out_w + x] = acc;
}

/* box_y: dst(p, y, x) = sum_{k=0..2r} src(p, y + k, x), every plane (launch w x planes * out_h; the
 * plane is gid1 / out_h). Output y is input row y + r: height shrinks by 2r. Halo r along y. */
__kernel void box_y(__global const float *restrict src, __global float *restrict dst, const int r,
                    const int w, const int in_h, const int out_h)
{
    const int x = get_global_id(0);
    const int g = get_global_id(1);
    const int p = g / out_h, y = g - p * out_h;
    __global const float *s = src + (p * in_h + y) * w + x;
    float acc = 0.0f;
    for (int k = 0; k <= 2 * r; ++k)
        acc += s[k * w];
    dst[g * w + x] = acc;
}

/* gf_products: the six masked products of guide x and target y at every pixel, planes of out (w x h):
 * m, m x, m y, m x x, m y y, m x y (m = 1 without GF_MASKED). x, y, m are planes of w x h images
 * starting at elements x_base, y_base, m_base. Halo 0. */
__kernel void gf_products(__global const float *restrict xs, __global const float *restrict ys,
                          __global const float *restrict ms, __global float *restrict out, const int w,
                          const int h, const int x_base, const int y_base, const int m_base)
{
    const int i = get_global_id(1) * w + get_global_id(0);
    const int plane = w * h;
    const float x = xs[x_base + i], y = ys[y_base + i];
#if GF_MASKED
    const float m = ms[m_base + i];
#else
    const float m = 1.0f;
#endif
    const float mx = m * x, my = m * y;
    out[i] = m;
    out[plane + i] = mx;
    out[2 * plane + i] = my;
    out[3 * plane + i] = mx * x;
    out[4 * plane + i] = my * y;
    out[5 * plane + i] = mx * y;
}

/* gf_coefficients: from the six window sums of gf_products (planes of sums, w x h; same order) the fit
 * y ~ a x + b of each window: n = max(sum m, 1), means, var_x, var_y, cov (over n);
 * a = cov / (var_x + eps), b = mean_y - a mean_x. Plain: out planes a, b. GF_WEIGHTED (ARI):
 * mse = a^2 var_x - 2 a cov + var_y, wt = 1 / max(sqrt(max(mse, 0)), GF_RMSE_FLOOR), out planes a wt,
 * b wt, wt. Halo 0. eps in the squared units of x. */
__kernel void gf_coefficients(__global const float *restrict sums, __global float *restrict out, const int w,
                              const int h, const float eps)
{
    const int i = get_global_id(1) * w + get_global_id(0);
    const int plane = w * h;
    const float sn = sums[i];
    const float n = sn > GF_MIN_COUNT ? sn : GF_MIN_COUNT;
    const float inv = 1.0f / n;
    const float mean_x = sums[plane + i] * inv, mean_y = sums[2 * plane + i] * inv;
    const float var_x = sums[3 * plane + i] * inv - mean_x * mean_x;
    const float cov = sums[5 * plane + i] * inv - mean_x * mean_y;
    const float a = cov / (var_x + eps);
    const float b = mean_y - a * mean_x;
#if GF_WEIGHTED
    const float var_y = sums[4 * plane + i] * inv - mean_y * mean_y;
    const float mse = a * a * var_x - 2.0f * a * cov + var_y;
    const float rmse = sqrt(mse > 0.0f ? mse : 0.0f);
    const float wt = 1.0f / (rmse > GF_RMSE_FLOOR ? rmse : GF_RMSE_FLOOR);
    out[i] = a * wt;
    out[plane + i] = b * wt;
    out[2 * plane + i] = wt;
#else
    out[i] = a;
    out[plane + i] = b;
#endif
}

/* gf_apply: q = (A x + B) / D at every output pixel, A, B (and W) the window sums of gf_coefficients'
 * planes (w x h); D = count (the window's pixel count, (2ry+1)(2rx+1): plain means over every pixel)
 * or, GF_WEIGHTED, W + GF_WEIGHT_REG. The guide x is read at element x_base + y x_w + x (the host
 * points x_base at the output's pixel in the guide window). Halo 0. */
__kernel void gf_apply(__global const float *restrict coef, __global const float *restrict xs,
                       __global float *restrict out, const int w, const int h, const int x_base,
                       const int x_w, const float count)
{
    const int gx = get_global_id(0), gy = get_global_id(1);
    const int i = gy * w + gx;
    const int plane = w * h;
    const float x = xs[x_base + gy * x_w + gx];
#if GF_WEIGHTED
    const float d = coef[2 * plane + i] + GF_WEIGHT_REG;
#else
    const float d = count;
#endif
    out[i] = (coef[i] * x + coef[plane + i]) / d;
}
