/* Luminance-guided multiresolution chroma denoising (clisp/modules/chroma_denoise/stage.py).
 * One kernel per step, named after the reference function it mirrors. Planar float32 images;
 * a "level" image holds NPLANES = 1 + NCHROMA planes (Y, then the chroma planes); a "detail" image
 * holds 3 x NPLANES planes from haar_analyze, 3 x NCHROMA after bayes_shrink, orientation-major
 * (dx, dy, dd). Defines from the host: NCHROMA, RADIUS (bilateral), SHRINK_RADIUS and SHRINK_RULE
 * (detail shrinkage), VEC (pixels per work item), INTERLEAVED (chroma_merge). Per tile:
 * chroma_split; J x (haar_analyze, bayes_shrink); from level J down: joint_bilateral,
 * haar_synthesize; joint_bilateral at level 0; chroma_merge. */

#define NPLANES (NCHROMA + 1)

/* VEC (define, 1 or 8): pixels along x per work item in every kernel. PoCL on
 * CPUs does not vectorise the scalar kernels across work items; explicit float8 made them 8x and
 * 2x cheaper there (a 1.5 MP single-plane 7x7 bilateral 0.54 -> 0.064 CPU-s; the whole stage's
 * bayes_shrink 0.15 -> 0.07 CPU-s). GPUs use VEC = 1 (one pixel per lane, coalesced). */
/* PoCL 3.0 (this build) calls vload8 / vstore8 / fmax / select / min as out-of-line functions,
 * also inside the hot loops (three calls per joint_bilateral tap); loads and stores through an
 * under-aligned vector type and ?: compile inline (24 MP Bayer: joint_bilateral 1.15 -> 0.93 s,
 * bayes_shrink 0.43 -> 0.10 s with its column sums). */
#if VEC == 8
typedef float8 floatv;
typedef float8 floatv_u __attribute__((aligned(4)));
typedef float4 float4_u __attribute__((aligned(4)));
#define AS_FLOATV as_float8
#define AS_INTV as_int8
#else
typedef float floatv;
typedef float floatv_u;
#define AS_FLOATV as_float
#define AS_INTV as_int
#endif
#define LOADV(p) (*(__global const floatv_u *)(p))
#define STOREV(v, p) (*(__global floatv_u *)(p) = (v))
/* max(a, b) and min(a, b) of floatv a and floatv or float b, inline (see above). */
#define MAXV(a, b) ((a) > (floatv)(b) ? (a) : (floatv)(b))

/* exp(x) for x <= 0, as the bilateral weights need it: x / ln2 = n + f, n = round(x / ln2), |f| <= 1/2,
 * degree-5 polynomial for 2^f (least-maximum relative error, 2.3e-7 evaluated in float32, against
 * 1.3e-7 of the degree-6 Taylor polynomial of e^f used before, 2 operations more), 2^n added to the
 * exponent bits. n by adding 1.5 2^23, which leaves n in the low mantissa bits of r (shifted into the
 * exponent field as is): floor() and convert_int() cost PoCL out-of-line code (joint_bilateral
 * 2.11 -> 1.15 s on 24 MP Bayer). x is clamped at EXP_CUT: the weight is then e^-40 = 4e-18, far
 * below float resolution of the centre weight (1), and no weight or weight * value product becomes
 * denormal (x86 handles those in microcode). Written out because PoCL's exp() is a scalar library
 * call. */
#define EXP_CUT (-40.0f)
inline floatv exp_neg(const floatv x)
{
    const floatv t = MAXV(x, EXP_CUT) * 1.44269504089f;
    const floatv r = t + 12582912.0f;              /* 1.5 2^23: n = round(t) in the low bits */
    const floatv f = t - (r - 12582912.0f);
    const floatv p = 1.00000012f + f * (0.693146944f + f * (0.240221202f + f * (0.0555071309f
                   + f * (0.00967554096f + f * 0.00132764713f))));
    return AS_FLOATV(AS_INTV(p) + (AS_INTV(r) << 23));
}

/* chroma_split: planes (Y, c_1..c_n) = m . camera, m row-major (NPLANES x 3), read from the window
 * at (y + skip_y, x + skip_x) (the first pixel aligned to the decimation grid). Halo 0. VEC
 * consecutive pixels per work item (width >= VEC; the last one of a row starts at width - VEC). */
__kernel void chroma_split(__global const float *restrict src, __global float *restrict dst,
                           const int src_w, const int src_h, const int skip_y, const int skip_x,
                           const int width, const int height, __constant const float *restrict m)
{
    const int gx = (int)get_global_id(0) * VEC;
    const int x = gx < width - VEC ? gx : width - VEC;
    const int y = get_global_id(1);
    if (gx >= width || y >= height) return;
    const int src_plane = src_w * src_h;
    const int si = (y + skip_y) * src_w + x + skip_x;
    const floatv l = LOADV(src + si), mm = LOADV(src + src_plane + si), s = LOADV(src + 2 * src_plane + si);
    const int plane = width * height;
    const int i = y * width + x;
    #pragma unroll
    for (int p = 0; p < NPLANES; ++p)
        STOREV(m[3 * p] * l + m[3 * p + 1] * mm + m[3 * p + 2] * s, dst + p * plane + i);
}

/* haar_analyze: one Haar level on 2 x 2 blocks (block means and differences / 4) of all NPLANES
 * planes: approximation (NPLANES planes) and details dx, dy, dd (3 x NPLANES planes, orientation
 * major). Output width x height, input 2 width x 2 height. Halo 0 (blocks on the aligned grid).
 * VEC consecutive outputs per work item (width >= VEC; the last one of a row starts at width - VEC):
 * two float8 loads per input row, split into even and odd columns. */
__kernel void haar_analyze(__global const float *restrict src, __global float *restrict approx, __global float *restrict detail,
                           const int width, const int height)
{
    const int gx = (int)get_global_id(0) * VEC;
    const int x = gx < width - VEC ? gx : width - VEC;
    const int y = get_global_id(1);
    if (gx >= width || y >= height) return;
    const int src_w = 2 * width;
    const int src_plane = 4 * width * height;
    const int plane = width * height;
    const int i = y * width + x;
    const int s0 = 2 * y * src_w + 2 * x;
    #pragma unroll
    for (int p = 0; p < NPLANES; ++p) {
        __global const float *a = src + p * src_plane + s0;
#if VEC == 8
        const float8 r0a = LOADV(a), r0b = LOADV(a + 8), r1a = LOADV(a + src_w), r1b = LOADV(a + src_w + 8);
        const float8 x00 = (float8)(r0a.even, r0b.even), x01 = (float8)(r0a.odd, r0b.odd);
        const float8 x10 = (float8)(r1a.even, r1b.even), x11 = (float8)(r1a.odd, r1b.odd);
#else
        const float x00 = a[0], x01 = a[1], x10 = a[src_w], x11 = a[src_w + 1];
#endif
        STOREV(0.25f * (x00 + x01 + x10 + x11), approx + p * plane + i);
        STOREV(0.25f * (x00 - x01 + x10 - x11), detail + p * plane + i);
        STOREV(0.25f * (x00 + x01 - x10 - x11), detail + (NPLANES + p) * plane + i);
        STOREV(0.25f * (x00 - x01 - x10 + x11), detail + (2 * NPLANES + p) * plane + i);
    }
}

/* window_energy: mean of d^2 over the (2 SHRINK_RADIUS + 1)^2 window centred on index ci
 * (VEC consecutive centres). VEC = 8, SHRINK_RADIUS = 2: column sums of the 12 columns the 8
 * windows cover (one float8 and one float4 load per row), then 5 shifted float8 sums of them
 * (28 vector operations instead of 50). */
inline floatv window_energy(__global const float *d, const int ci, const int in_w)
{
#if VEC == 8 && SHRINK_RADIUS == 2
    float8 a = 0.0f;
    float4 b = 0.0f;
    for (int dy = -2; dy <= 2; ++dy) {
        __global const float *p = d + ci + dy * in_w - 2;
        const float8 va = LOADV(p);
        const float4 vb = *(__global const float4_u *)(p + 8);
        a += va * va;
        b += vb * vb;
    }
    const floatv energy = a + (float8)(a.s1234, a.s567, b.s0) + (float8)(a.s2345, a.s67, b.s01)
                        + (float8)(a.s3456, a.s7, b.s012) + (float8)(a.s4567, b.s0123);
#else
    floatv energy = 0.0f;
    for (int dy = -SHRINK_RADIUS; dy <= SHRINK_RADIUS; ++dy)
        for (int dx = -SHRINK_RADIUS; dx <= SHRINK_RADIUS; ++dx) {
            const floatv v = LOADV(d + ci + dy * in_w + dx);
            energy += v * v;
        }
#endif
    return energy * (1.0f / (float)((2 * SHRINK_RADIUS + 1) * (2 * SHRINK_RADIUS + 1)));
}

/* bayes_shrink: shrink the chroma detail planes. Halo SHRINK_RADIUS: output (u, v) is input
 * (u + R_W, v + R_W). Input 3 x NPLANES detail planes (plane 0 of each orientation = Y), output
 * 3 x NCHROMA. With E = window_energy, var_n = strength2[k] (coef a max(Y, 0) + b) (Y = plane 0 of
 * the level image, same grid; coef per channel and orientation, Y first) and var_x = max(E - var_n, 0):
 * SHRINK_RULE 0 (BayesShrink soft): d' = sign(d) max(|d| - var_n / sqrt(var_x), 0), 0 if var_x = 0;
 * SHRINK_RULE 1 (Wiener): d' = d var_x / (var_x + var_n). guide != 0: d'' = d' + g_Y (d - d'),
 * g_Y = var_xY / (var_xY + var_nY), the Wiener gain of the luminance detail. VEC consecutive
 * outputs per work item, as in joint_bilateral (width >= VEC). */
__kernel void bayes_shrink(__global const float *restrict detail, __global const float *restrict level,
                           __global float *restrict dst, const int in_w, const int in_h,
                           const int width, const int height,
                           __constant const float *restrict coef, __constant const float *restrict strength2,
                           const int guide)
{
    const int gx = (int)get_global_id(0) * VEC;
    const int x = gx < width - VEC ? gx : width - VEC;
    const int y = get_global_id(1);
    if (gx >= width || y >= height) return;
    const int in_plane = in_w * in_h;
    const int plane = width * height;
    const int ci = (y + SHRINK_RADIUS) * in_w + x + SHRINK_RADIUS;
    const floatv s = MAXV(LOADV(level + ci), 0.0f);
    for (int o = 0; o < 3; ++o) {
        floatv g_y = 0.0f;
        if (guide) {
            const floatv var_ny = coef[2 * o] * s + coef[2 * o + 1];
            const floatv var_xy = MAXV(window_energy(detail + o * NPLANES * in_plane, ci, in_w) - var_ny, 0.0f);
            const floatv total = var_xy + var_ny;
            g_y = total > 0.0f ? var_xy / total : (floatv)0.0f;
        }
        for (int k = 0; k < NCHROMA; ++k) {
            __global const float *d = detail + (o * NPLANES + 1 + k) * in_plane;
            const int c = 2 * (3 * (1 + k) + o);
            const floatv var_n = strength2[k] * (coef[c] * s + coef[c + 1]);
            const floatv var_x = MAXV(window_energy(d, ci, in_w) - var_n, 0.0f);
            const floatv dc = LOADV(d + ci);
#if SHRINK_RULE == 1
            const floatv total = var_x + var_n;
            const floatv shrunk = total > 0.0f ? dc * var_x / total : (floatv)0.0f;
#else
            /* sign(d) max(|d| - t, 0) = d - clamp(d, -t, t), exactly; t = inf where var_x = 0 */
            const floatv t = var_x > 0.0f ? var_n / sqrt(var_x) : (floatv)INFINITY;
            const floatv shrunk = dc - (dc > t ? t : (dc < -t ? -t : dc));
#endif
            STOREV(shrunk + g_y * (dc - shrunk), dst + (o * NCHROMA + k) * plane + y * width + x);
        }
    }
}

/* The constants of one joint_bilateral launch (one pyramid level), field by field as the host's record
 * (ChromaDenoise.bilateral_constants, dtype BILATERAL_CONSTANTS): range variances
 * luma[0] max(Y, 0) + luma[1] and chroma[2k] max(Y, 0) + chroma[2k + 1] (already times k^2 and
 * s_k^2), floored at floor2; metric M (n x n, row-major) of the joint range term. */
typedef struct {
    float inv_2sd2;                    /* 1 / (2 sigma_d^2), sigma_d the spatial sigma in pixels */
    float floor2;                      /* the range variances' floor, sigma_floor^2 */
    float luma[2];                     /* aY, bY */
    float chroma[2 * NCHROMA];         /* a_1, b_1, ..., a_n, b_n */
    float metric[NCHROMA * NCHROMA];   /* M (JOINT_RANGE) */
} bilateral_constants;

/* joint_bilateral: luminance-guided bilateral of NCHROMA chroma planes. Halo RADIUS: output (u, v)
 * is centred on chroma pixel (u + R, v + R) (planes at src + c_offset, c_w x c_h) and on luminance
 * pixel (u + R + y_shift, v + R + y_shift) of the level image (plane 0, y_w wide). prm: the
 * level's bilateral_constants. guide = 0 drops the Y
 * term. w = exp(-(|q-p|^2/(2 sd^2) + (Y_q - Y_p)^2/(2 sY^2) + (c_q - c_p)^2/(2 sc^2))), per plane;
 * with JOINT_RANGE one w for every plane, its chroma term z^T M z, z_k = (c_q,k - c_p,k)/(sqrt2 sc_k)
 * (ChromaDenoise.range_metric).
 * All planes in one pass: the guide tap and its spatial + luminance term are read and computed once
 * per tap for every plane. Each work item computes VEC consecutive pixels of a row (width >= VEC);
 * the last one of a row starts at width - VEC, recomputing a few pixels with identical results. */
__kernel void joint_bilateral(__global const float *restrict src, const int c_offset, __global const float *restrict level,
                              __global float *restrict dst, const int c_w, const int c_h, const int y_w,
                              const int y_shift, const int width, const int height, const int guide,
                              __constant const bilateral_constants *restrict prm)
{
    const int gx = (int)get_global_id(0) * VEC;
    const int x = gx < width - VEC ? gx : width - VEC;
    const int y = get_global_id(1);
    if (gx >= width || y >= height) return;
    const int c_plane = c_w * c_h;
    const int plane = width * height;
    const int ci = (y + RADIUS) * c_w + x + RADIUS;
    const int yi = (y + RADIUS + y_shift) * y_w + x + RADIUS + y_shift;
    __global const float *c = src + c_offset + ci;
    __global const float *g = level + yi;
    const float inv2sd2 = prm->inv_2sd2, floor2 = prm->floor2;
    __constant const float *metric = prm->metric;                /* M, n x n (JOINT_RANGE) */
    const floatv yp = LOADV(g);
    const floatv s = MAXV(yp, 0.0f);
    const floatv inv_y = guide ? 0.5f / MAXV(prm->luma[0] * s + prm->luma[1], floor2) : (floatv)0.0f;
    floatv cp[NCHROMA], inv_c[NCHROMA], num[NCHROMA], den[NCHROMA];
#if JOINT_RANGE
    floatv sq_c[NCHROMA];
#endif
    #pragma unroll
    for (int k = 0; k < NCHROMA; ++k) {
        cp[k] = LOADV(c + k * c_plane);
        inv_c[k] = 0.5f / MAXV(prm->chroma[2 * k] * s + prm->chroma[2 * k + 1], floor2);
#if JOINT_RANGE
        sq_c[k] = sqrt(inv_c[k]);
#endif
        num[k] = 0.0f;
        den[k] = 0.0f;
    }
    #pragma unroll
    for (int dy = -RADIUS; dy <= RADIUS; ++dy) {
        #pragma unroll
        for (int dx = -RADIUS; dx <= RADIUS; ++dx) {
            const floatv dyq = LOADV(g + dy * y_w + dx) - yp;
            const floatv base = (float)(dy * dy + dx * dx) * inv2sd2 + dyq * dyq * inv_y;
#if JOINT_RANGE
            floatv cq[NCHROMA], z[NCHROMA];
            #pragma unroll
            for (int k = 0; k < NCHROMA; ++k) {
                cq[k] = LOADV(c + k * c_plane + dy * c_w + dx);
                z[k] = (cq[k] - cp[k]) * sq_c[k];
            }
            floatv rng = 0.0f;
            #pragma unroll
            for (int k = 0; k < NCHROMA; ++k) {
                floatv mz = 0.0f;
                #pragma unroll
                for (int l = 0; l < NCHROMA; ++l)
                    mz += metric[k * NCHROMA + l] * z[l];
                rng += z[k] * mz;
            }
            const floatv w = exp_neg(-(base + rng));
            #pragma unroll
            for (int k = 0; k < NCHROMA; ++k) {
                num[k] += w * cq[k];
                den[k] += w;
            }
#else
            #pragma unroll
            for (int k = 0; k < NCHROMA; ++k) {
                const floatv cq = LOADV(c + k * c_plane + dy * c_w + dx);
                const floatv dc = cq - cp[k];
                const floatv w = exp_neg(-(base + dc * dc * inv_c[k]));
                num[k] += w * cq;
                den[k] += w;
            }
#endif
        }
    }
    #pragma unroll
    for (int k = 0; k < NCHROMA; ++k)
        STOREV(num[k] / den[k], dst + k * plane + y * width + x);
}

/* haar_synthesize: inverse of haar_analyze for the NCHROMA chroma planes:
 * x_(sy,sx) = a + sx dx + sy dy + sx sy dd, sx = +1 on even columns, -1 on odd (sy
 * alike). approx: NCHROMA planes a_w x a_h. detail: d_planes planes per orientation, d_w x d_h,
 * chroma k at plane d_first + k; coefficient (u + d_shift, v + d_shift) for approx (u, v).
 * Output 2 a_w x 2 a_h. Halo 0. VEC consecutive outputs per work item (2 a_w >= VEC; the last one
 * of a row starts at 2 a_w - VEC, even): VEC / 2 coefficients, even and odd columns interleaved. */
__kernel void haar_synthesize(__global const float *restrict approx, __global const float *restrict detail,
                              __global float *restrict dst, const int a_w, const int a_h,
                              const int d_w, const int d_h, const int d_shift,
                              const int d_planes, const int d_first)
{
    const int width = 2 * a_w, height = 2 * a_h;
    const int gx = (int)get_global_id(0) * VEC;
    const int x = gx < width - VEC ? gx : width - VEC;
    const int y = get_global_id(1);
    if (gx >= width || y >= height) return;
    const int u = y >> 1, v = x >> 1;
    const float sy = (y & 1) ? -1.0f : 1.0f;
    const int ai = u * a_w + v;
    const int di = (u + d_shift) * d_w + v + d_shift;
    const int a_plane = a_w * a_h, d_plane = d_w * d_h, plane = width * height;
    #pragma unroll
    for (int k = 0; k < NCHROMA; ++k) {
#if VEC == 8
        const float4 a = *(__global const float4_u *)(approx + k * a_plane + ai);
        const float4 ddx = *(__global const float4_u *)(detail + (d_first + k) * d_plane + di);
        const float4 ddy = *(__global const float4_u *)(detail + (d_planes + d_first + k) * d_plane + di);
        const float4 ddd = *(__global const float4_u *)(detail + (2 * d_planes + d_first + k) * d_plane + di);
        const float4 e = a + ddx + sy * ddy + sy * ddd;        /* sx = +1 */
        const float4 o = a - ddx + sy * ddy - sy * ddd;        /* sx = -1 */
        STOREV((float8)(e.s0, o.s0, e.s1, o.s1, e.s2, o.s2, e.s3, o.s3), dst + k * plane + y * width + x);
#else
        const float sx = (x & 1) ? -1.0f : 1.0f;
        const float a = approx[k * a_plane + ai];
        const float ddx = detail[(d_first + k) * d_plane + di];
        const float ddy = detail[(d_planes + d_first + k) * d_plane + di];
        const float ddd = detail[(2 * d_planes + d_first + k) * d_plane + di];
        dst[k * plane + y * width + x] = a + sx * ddx + sy * ddy + sx * sy * ddd;
#endif
    }
}

/* The output element of chroma_merge: float, or with ENCODE_SRGB (the pipeline's tone curve folded
 * into this stage's store; the host prepends clisp/modules/colour/srgb.h) the sRGB-encoded value,
 * as QUANTIZE codes of CODE_BITS (16: ushort, 8: uchar) or float. ENC1 encodes one value, ENC8
 * eight (encode_srgb8: only what PoCL compiles inline). */
#if ENCODE_SRGB && QUANTIZE && CODE_BITS == 8
typedef uchar out_t;
typedef uchar8 out8_u __attribute__((aligned(1)));
#define ENC1(v) quantize8(encode_srgb(v))
#define ENC8(v) quantize8x8(encode_srgb8(v))
#elif ENCODE_SRGB && QUANTIZE
typedef ushort out_t;
typedef ushort8 out8_u __attribute__((aligned(2)));
#define ENC1(v) quantize16(encode_srgb(v))
#define ENC8(v) quantize16x8(encode_srgb8(v))
#elif ENCODE_SRGB
typedef float out_t;
typedef float8 out8_u __attribute__((aligned(4)));
#define ENC1(v) encode_srgb(v)
#define ENC8(v) encode_srgb8(v)
#else
typedef float out_t;
typedef float8 out8_u __attribute__((aligned(4)));
#define ENC1(v) (v)
#define ENC8(v) (v)
#endif

/* chroma_merge: RGB = m . (Y, c_1..c_n), m row-major (3 x NPLANES). Output (u, v) reads chroma
 * (u + c_shift_y, v + c_shift_x) of c_w x c_h planes and Y (u + y_shift_y, v + y_shift_x) of the
 * level-0 image (y_w wide). Halo 0. INTERLEAVED (define): write H x W x 3 (the host layout, when
 * this is the pipeline's last stage) instead of 3 planes; ENCODE_SRGB: store the tone curve's
 * output (out_t above). VEC consecutive pixels per work item (width >= VEC; the last one of a row
 * starts at width - VEC). */
__kernel void chroma_merge(__global const float *restrict level, __global const float *restrict chroma, __global out_t *restrict dst,
                           const int y_w, const int y_shift_y, const int y_shift_x,
                           const int c_w, const int c_h, const int c_shift_y, const int c_shift_x,
                           const int width, const int height, __constant const float *restrict m)
{
    const int gx = (int)get_global_id(0) * VEC;
    const int x = gx < width - VEC ? gx : width - VEC;
    const int y = get_global_id(1);
    if (gx >= width || y >= height) return;
    const floatv lum = LOADV(level + (y + y_shift_y) * y_w + x + y_shift_x);
    const int c_plane = c_w * c_h;
    const int ci = (y + c_shift_y) * c_w + x + c_shift_x;
    floatv c[NCHROMA], rgb[3];
    #pragma unroll
    for (int k = 0; k < NCHROMA; ++k)
        c[k] = LOADV(chroma + k * c_plane + ci);
    #pragma unroll
    for (int r = 0; r < 3; ++r) {
        floatv v = m[r * NPLANES] * lum;
        #pragma unroll
        for (int k = 0; k < NCHROMA; ++k)
            v += m[r * NPLANES + 1 + k] * c[k];
        rgb[r] = v;
    }
    const int i = y * width + x;
#if INTERLEAVED && VEC == 8
    const float8 r = rgb[0], g = rgb[1], b = rgb[2];
    __global out8_u *o = (__global out8_u *)(dst + 3 * i);
    o[0] = ENC8(((float8)(r.s0, g.s0, b.s0, r.s1, g.s1, b.s1, r.s2, g.s2)));
    o[1] = ENC8(((float8)(b.s2, r.s3, g.s3, b.s3, r.s4, g.s4, b.s4, r.s5)));
    o[2] = ENC8(((float8)(g.s5, b.s5, r.s6, g.s6, b.s6, r.s7, g.s7, b.s7)));
#elif INTERLEAVED
    dst[3 * i] = ENC1(rgb[0]);
    dst[3 * i + 1] = ENC1(rgb[1]);
    dst[3 * i + 2] = ENC1(rgb[2]);
#elif VEC == 8
    const int plane = width * height;
    #pragma unroll
    for (int r = 0; r < 3; ++r)
        *(__global out8_u *)(dst + r * plane + i) = ENC8(rgb[r]);
#else
    const int plane = width * height;
    #pragma unroll
    for (int r = 0; r < 3; ++r)
        dst[r * plane + i] = ENC1(rgb[r]);
#endif
}
