/* Building blocks of the masked guided filter of the residual-interpolation Bayer demosaics (RI, MLRI,
 * ARI; NumPy float64 reference: clisp/modules/demosaic_ari/reference.py, guided_filter / WindowStats / _fit). Host side:
 * clisp/modules/common/guided_ri.py. Windows are ("box", ry, rx) rectangles, (2ry+1) x (2rx+1) pixels.
 *
 * Run in this order for one filter of target y against guide x over the mask m (all H x W):
 *   gf_row_moments(rx) -> gf_col_coefficients(ry)               halo rx along x, ry along y
 *     (centred statistics, the default; or, uncentred: gf_products (6 planes m, m x, m y, m x^2,
 *     m y^2, m x y; halo 0) -> box_x(rx), box_y(ry) -> gf_coefficients (halo 0))
 *     -> planes a, b (weighted: a w, b w, w)
 *   box_x(rx), box_y(ry) of those planes                        halo rx, ry
 *   gf_apply (q = (sum a) x + sum b, over the count or sum w)   halo 0
 * Total halo 2ry along y, 2rx along x: an H x W window gives its (H - 4ry) x (W - 4rx) interior.
 *
 * Tiling convention: every kernel reads a window already padded by its halo and writes the interior;
 * images are planar float32 (plane p of an h x w image starts at p h w); no bounds checks (the host
 * launches exactly the outputs, runtime.launch_exact). Units are the caller's (ARI: 8-bit, 0..255).
 * Uncentred statistics (gf_products) are plain sums in float32: var = E[x^2] - E[x]^2 loses ~1e-7 E[x^2] to
 * cancellation (~4e-3 at 255), so a window whose guide variance is below that (flat areas) gets an
 * ill-conditioned slope a. The centred kernels below avoid this and are what the host runs by default.
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

/* BOX_RADIUS(r): the box kernels' radius, the define GF_BOX_R when the host builds a program per
 * radius (the loop unrolls and PoCL vectorises the kernel), else the runtime argument r. */
#ifdef GF_BOX_R
#define BOX_RADIUS(r) GF_BOX_R
#else
#define BOX_RADIUS(r) (r)
#endif

/* box_x: dst(p, y, x) = sum_{k=0..2r} src(p, y, x + k), every plane (planes stacked along y: launch
 * out_w x planes * h). Output x is input column x + r: width shrinks by 2r. Halo r along x. */
__kernel void box_x(__global const float *restrict src, __global float *restrict dst, const int r,
                    const int in_w, const int out_w)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    __global const float *s = src + y * in_w + x;
    float acc = 0.0f;
#pragma unroll
    for (int k = 0; k <= 2 * BOX_RADIUS(r); ++k)
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
#pragma unroll
    for (int k = 0; k <= 2 * BOX_RADIUS(r); ++k)
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

/* store_coefficients: the guided filter's a = cov / (var_x + eps), b = mean_y - a mean_x of one
 * window, written at index i of the planes of out (plane stride ``plane``): a, b (plain), or a w,
 * b w, w with w = 1 / max(RMSE of the fit, GF_RMSE_FLOOR) (weighted: ARI). */
inline void store_coefficients(__global float *restrict out, const int i, const int plane,
                               const float mean_x, const float mean_y, const float var_x,
                               const float var_y, const float cov, const float eps)
{
    const float a = cov / (var_x + eps);
    const float b = mean_y - a * mean_x;
#if GF_WEIGHTED
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
    const float var_y = sums[4 * plane + i] * inv - mean_y * mean_y;   /* unused unless weighted */
    store_coefficients(out, i, plane, mean_x, mean_y, var_x, var_y, cov, eps);
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

/* ---- Centred statistics (what device_guided_filter runs by default): the same window sums as
 * gf_products -> box_x -> box_y -> gf_coefficients, with x and y centred on their values at the window's
 * centre pixel, so that var = E[d^2] - E[d]^2 cancels only at the scale of the local spread of x, not
 * of x itself (uncentred float32 sums lose ~4e-3 at 255; measured, tests/test_guided_filter_cl.py: the weighted filter's error on a
 * noisy ramp falls from 2.2e-3 x 255 to 1.7e-5 x 255, the plain one from 2.8e-4 to 3e-7). Two kernels
 * replace those four:
 *   gf_row_moments: sums along x, centred on the row's centre pixel            halo rx along x
 *   gf_col_coefficients: sums along y, each row's sums moved to the centre of   halo ry along y
 *     the window (exact algebra), then a, b (and the weights) as gf_coefficients */

/* gf_row_moments: for output (y, x) <-> input (y, x + r), centres cx = x(y, x + r), cy = y(y, x + r),
 * d = x - cx, e = y - cy over k = 0..2r at input (y, x + k): planes of out (out_w x h): sum m, sum m d,
 * sum m e, sum m d^2, sum m e^2, sum m d e. Inputs: planes of in_w x h images from x_base, y_base,
 * m_base. Halo r along x (width shrinks by 2r). */
__kernel void gf_row_moments(__global const float *restrict xs, __global const float *restrict ys,
                             __global const float *restrict ms, __global float *restrict out, const int r,
                             const int in_w, const int out_w, const int h, const int x_base, const int y_base,
                             const int m_base)
{
    const int x = get_global_id(0), y = get_global_id(1);
    const int at = y * in_w + x;
    __global const float *xr = xs + x_base + at, *yr = ys + y_base + at;
    const float cx = xr[r], cy = yr[r];
    float n = 0.0f, sd = 0.0f, se = 0.0f, sdd = 0.0f, see = 0.0f, sde = 0.0f;
    for (int k = 0; k <= 2 * r; ++k) {
#if GF_MASKED
        const float m = ms[m_base + at + k];
#else
        const float m = 1.0f;
#endif
        const float d = xr[k] - cx, e = yr[k] - cy;
        const float md = m * d, me = m * e;
        n += m;
        sd += md;
        se += me;
        sdd += md * d;
        see += me * e;
        sde += md * e;
    }
    const int i = y * out_w + x, plane = out_w * h;
    out[i] = n;
    out[plane + i] = sd;
    out[2 * plane + i] = se;
    out[3 * plane + i] = sdd;
    out[4 * plane + i] = see;
    out[5 * plane + i] = sde;
}

/* gf_col_coefficients: rows (6 planes of gf_row_moments, w x in_h) summed over rows j = y .. y + 2r,
 * each moved from its centres (cx_j, cy_j) to the output's (cx, cy) = row y + r's: with dx = cx_j - cx,
 * dy = cy_j - cy: S1 += s1 + n dx, S2 += s2 + 2 dx s1 + n dx^2, Sxy += sde + dx se + dy sd + n dx dy.
 * The centres are read from the guide and target planes (x_base, y_base, row pitch x_w; element
 * x_base + j x_w + x is the centre of row moments (j, x)). Then N = sum m, n = max(N, 1),
 * mean_x = cx N / n + S1x / n, var_x = S2x / n - (S1x / n)^2 (likewise y), cov = Sxy / n - S1x S1y / n^2,
 * and a, b (weighted: a w, b w, w) exactly as gf_coefficients; out planes w x out_h. Halo r along y. */
__kernel void gf_col_coefficients(__global const float *restrict rows, __global const float *restrict xs,
                                  __global const float *restrict ys, __global float *restrict out, const int r,
                                  const int w, const int in_h, const int out_h, const int x_base,
                                  const int y_base, const int x_w, const float eps)
{
    const int x = get_global_id(0), y = get_global_id(1);
    const int rp = w * in_h;
    const float cx = xs[x_base + (y + r) * x_w + x], cy = ys[y_base + (y + r) * x_w + x];
    float n = 0.0f, s1x = 0.0f, s1y = 0.0f, s2x = 0.0f, s2y = 0.0f, sxy = 0.0f;
    for (int j = 0; j <= 2 * r; ++j) {
        const int i = (y + j) * w + x;
        const float dx = xs[x_base + (y + j) * x_w + x] - cx, dy = ys[y_base + (y + j) * x_w + x] - cy;
        const float nj = rows[i], sd = rows[rp + i], se = rows[2 * rp + i];
        n += nj;
        s1x += sd + nj * dx;
        s1y += se + nj * dy;
        s2x += rows[3 * rp + i] + dx * (2.0f * sd + nj * dx);
        s2y += rows[4 * rp + i] + dy * (2.0f * se + nj * dy);
        sxy += rows[5 * rp + i] + dx * se + dy * sd + nj * dx * dy;
    }
    const float nn = n > GF_MIN_COUNT ? n : GF_MIN_COUNT;
    const float inv = 1.0f / nn;
    const float md = s1x * inv, me = s1y * inv;
    const float mean_x = cx * (n * inv) + md, mean_y = cy * (n * inv) + me;
    const float var_x = s2x * inv - md * md;
    const float cov = sxy * inv - md * me;
    const float var_y = s2y * inv - me * me;                          /* unused unless weighted */
    store_coefficients(out, y * w + x, w * out_h, mean_x, mean_y, var_x, var_y, cov, eps);
}
