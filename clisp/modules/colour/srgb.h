/* sRGB encoding (IEC 61966-2-1) in plain arithmetic, for kernels that end a pipeline in integer
 * output. On PoCL pow(), sqrt(), clamp() and even mad() are scalar library calls that stop a kernel
 * from vectorising (pow: 17 M values/s on 2 cores); products, sums, compares and integer bit
 * operations vectorise. Above the threshold, with v = 2^e m (m in [1, 2)):
 *   1.055 v^(1/2.4) - 0.055 = [1.055 m^(1/2.4)] * 2^(e/2.4) - 0.055,
 * the bracket a degree-6 polynomial in m (SRGB_M*), and 2^(e/2.4) = 2^n 2^f with n = floor(e/2.4),
 * 2^f a degree-5 polynomial (SRGB_F*) and 2^n from the exponent bits. Coefficients come from the
 * host (clisp.sim.colorimetry.srgb_poly_defines); the curve is within 0.02 of a 16-bit code over every
 * float in [threshold, 1] (tests/modules/test_kernels.py). Needs the SRGB_* defines of SRGB_ENCODING too. */

/* encode_srgb: clip to [0, 1], then the sRGB transfer function. */
inline float encode_srgb(const float x)
{
    const float v = x < SRGB_THRESHOLD ? SRGB_THRESHOLD : (x > 1.0f ? 1.0f : x);
    const uint bits = as_uint(v);
    const float u = as_float((bits & 0x007fffffu) | 0x3f800000u) * SRGB_M_SCALE + SRGB_M_OFFSET;
    const float pm = (((((SRGB_M6 * u + SRGB_M5) * u + SRGB_M4) * u + SRGB_M3) * u + SRGB_M2) * u
                      + SRGB_M1) * u + SRGB_M0;
    const float y = (float)((int)(bits >> 23) - 127) * SRGB_INV_GAMMA;       /* e / 2.4 <= 0 */
    const int n = (int)(y + 64.0f) - 64;                                     /* floor(y) */
    const float w = (y - (float)n) * SRGB_F_SCALE + SRGB_F_OFFSET;
    const float pf = ((((SRGB_F5 * w + SRGB_F4) * w + SRGB_F3) * w + SRGB_F2) * w + SRGB_F1) * w + SRGB_F0;
    const float curve = pm * pf * as_float((uint)(n + 127) << 23) - SRGB_OFFSET;
    const float linear = x > 0.0f ? SRGB_SLOPE * x : 0.0f;
    return x <= SRGB_THRESHOLD ? linear : curve;
}

/* quantize16: an encoded value to the nearest 16-bit code. It must lie in [0, 1 + 1e-6], as every
 * encode_srgb result does (a value past 65535.5 would wrap): clamping here again made PoCL stop
 * vectorising the kernels that call it (143 against 830 M values/s). */
inline ushort quantize16(const float v)
{
    return (ushort)(int)(v * 65535.0f + 0.5f);         /* through int: vectorises */
}

/* encode_srgb8: encode_srgb of eight values at once, for kernels that handle eight pixels per
 * work-item (their stores interleave channels: PoCL turns a scalar kernel's interleaved stores
 * into scattered scalar stores). The same operations in the same order, element-wise; only what
 * PoCL 3.0 compiles inline: no convert_* (out-of-line calls), integer <-> float by the 1.5 2^23
 * trick (exact for |values| < 2^22), selects by the vector ?: operator. */
inline float8 encode_srgb8(const float8 x)
{
    const float8 magic = (float8)12582912.0f;                           /* 1.5 2^23 */
    const float8 lo = (float8)SRGB_THRESHOLD, one = (float8)1.0f;
    const float8 v = x < lo ? lo : (x > one ? one : x);
    const uint8 bits = as_uint8(v);
    const float8 u = as_float8((bits & (uint8)0x007fffffu) | (uint8)0x3f800000u) * SRGB_M_SCALE + SRGB_M_OFFSET;
    const float8 pm = (((((SRGB_M6 * u + SRGB_M5) * u + SRGB_M4) * u + SRGB_M3) * u + SRGB_M2) * u
                      + SRGB_M1) * u + SRGB_M0;
    const float8 e = as_float8(as_int8(magic) + (as_int8(bits >> 23) - 127)) - magic;   /* (float)(e) */
    const float8 y = e * SRGB_INV_GAMMA;                                             /* e / 2.4 <= 0 */
    const float8 t = y + 64.0f;
    const float8 r = (t + magic) - magic;                                            /* round(t) */
    const float8 fl = r > t ? r - 1.0f : r;                                          /* floor(t) */
    const int8 n = (as_int8(fl + magic) - as_int8(magic)) - 64;                      /* floor(y) */
    const float8 w = (y - (fl - 64.0f)) * SRGB_F_SCALE + SRGB_F_OFFSET;
    const float8 pf = ((((SRGB_F5 * w + SRGB_F4) * w + SRGB_F3) * w + SRGB_F2) * w + SRGB_F1) * w + SRGB_F0;
    const float8 curve = pm * pf * as_float8((n + 127) << 23) - SRGB_OFFSET;
    const float8 zero = (float8)0.0f;
    const float8 linear = x > zero ? SRGB_SLOPE * x : zero;
    return x <= lo ? linear : curve;
}

/* quantize16x8: quantize16 of eight encoded values in [0, 1 + 1e-6]: the 16-bit code by the
 * 1.5 2^23 trick on v * 65535 + 0.5 truncated (as quantize16's (int) cast: the value is >= 0). */
inline ushort8 quantize16x8(const float8 v)
{
    const float8 magic = (float8)12582912.0f;
    const float8 t = v * 65535.0f + 0.5f;
    const float8 r = (t + magic) - magic;
    const float8 fl = r > t ? r - 1.0f : r;                                           /* trunc = floor */
    const uint8 code = as_uint8(fl + magic) - as_uint8(magic);
    return (ushort8)(code.s0, code.s1, code.s2, code.s3, code.s4, code.s5, code.s6, code.s7);
}

/* quantize8 / quantize8x8: an encoded value (one, eight) to the nearest 8-bit code, as quantize16
 * and quantize16x8 (JPEG output: the device writes the file's bytes, a third of float's). */
inline uchar quantize8(const float v)
{
    return (uchar)(int)(v * 255.0f + 0.5f);
}

inline uchar8 quantize8x8(const float8 v)
{
    const float8 magic = (float8)12582912.0f;
    const float8 t = v * 255.0f + 0.5f;
    const float8 r = (t + magic) - magic;
    const float8 fl = r > t ? r - 1.0f : r;
    const uint8 code = as_uint8(fl + magic) - as_uint8(magic);
    return (uchar8)(code.s0, code.s1, code.s2, code.s3, code.s4, code.s5, code.s6, code.s7);
}
