/* store.h: the output element type and store of a stage that may end in the sRGB tone curve.
 * Defines from the host: ENCODE_SRGB (1: store the encoded value; the host then prepends
 * clisp/modules/colour/srgb.h, with encode_srgb and quantize16), QUANTIZE (1: as codes of CODE_BITS,
 * 16 (ushort) or 8 (uchar); with ENCODE_SRGB only). Included by linear_filter.cl, half_size.cl and
 * colour.cl (the tone curve, which defines ENCODE_SRGB itself). */
#if ENCODE_SRGB && QUANTIZE && CODE_BITS == 8
typedef uchar out_t;
#define STORE(v) quantize8(encode_srgb(v))
typedef uchar8 out8_u __attribute__((aligned(1)));
#define ENCODE8(v) encode_srgb8(v)
#define CODE8(v) quantize8x8(v)
#elif ENCODE_SRGB && QUANTIZE
typedef ushort out_t;
#define STORE(v) quantize16(encode_srgb(v))
typedef ushort8 out8_u __attribute__((aligned(2)));
#define ENCODE8(v) encode_srgb8(v)
#define CODE8(v) quantize16x8(v)
#elif ENCODE_SRGB
typedef float out_t;
#define STORE(v) encode_srgb(v)
typedef float8 out8_u __attribute__((aligned(4)));
#define ENCODE8(v) encode_srgb8(v)
#define CODE8(v) (v)
#else
typedef float out_t;
#define STORE(v) (v)
typedef float8 out8_u __attribute__((aligned(4)));
#define ENCODE8(v) (v)
#define CODE8(v) (v)
#endif

/* The kernels that handle eight pixels of a row per work-item (CPU devices): work-item gx covers
 * columns eight_from(8 gx, width) .. + 7, the last of a row starting at width - 8 (it rewrites a few
 * pixels with the same values, so width >= 8); float8_u reads eight floats of a plane unaligned. */
inline int eight_from(const int gx, const int width)
{
    return gx < width - 8 ? gx : width - 8;
}
typedef float8 float8_u __attribute__((aligned(4)));

/* store_rgb8: eight neighbouring pixels' channels (r, g, b, one float8 each, linear as STORE takes
 * them) written H x W x 3 from dst: encoded (ENCODE8), their 24 values then shuffled into three
 * consecutive vectors and stored as codes (CODE8), the values STORE gives each pixel. For kernels
 * that handle eight pixels per work-item on CPU devices: PoCL turns a scalar kernel's interleaved
 * stores into scattered scalar stores (16-bit codes of 24 MP: 177 MP/s interleaved against 500
 * planar). Encoded before the shuffle: encoding after it made phase_filter_px8 about 8 % slower. */
inline void store_rgb8(__global out_t *dst, const float8 linear_r, const float8 linear_g, const float8 linear_b)
{
    const float8 r = ENCODE8(linear_r), g = ENCODE8(linear_g), b = ENCODE8(linear_b);
    __global out8_u *o = (__global out8_u *)dst;
    o[0] = CODE8(((float8)(r.s0, g.s0, b.s0, r.s1, g.s1, b.s1, r.s2, g.s2)));
    o[1] = CODE8(((float8)(b.s2, r.s3, g.s3, b.s3, r.s4, g.s4, b.s4, r.s5)));
    o[2] = CODE8(((float8)(g.s5, b.s5, r.s6, g.s6, b.s6, r.s7, g.s7, b.s7)));
}
