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
