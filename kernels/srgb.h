/* sRGB encoding (IEC 61966-2-1) by table, for the kernels that end a pipeline in integer output.
 * The host prepends the table (clisp.colorimetry.srgb_table_source): SRGB_LUT[] holds the exact
 * transfer function at SRGB_LUT_STEPS points per octave of the float's binary exponent, from
 * 2^-SRGB_LUT_OCTAVES to 1, and SRGB_LUT_BASE is the table's first float bit pattern >> SRGB_LUT_SHIFT.
 * Interpolating linearly in the mantissa is exact at the nodes; in between its error is at most
 * 0.1 of a 16-bit code: 0.097 measured over every float in [2^-9, 1] (tests/test_kernels.py checks
 * every 7th).
 * pow() is a scalar library call on PoCL (17 M values/s on 2 cores); this vectorises (about 500 M). */

/* encode_srgb: clip to [0, 1], then the sRGB transfer function. */
inline float encode_srgb(const float x)
{
    const float v = clamp(x, 0.0f, 1.0f);
    const uint bits = as_uint(fmax(v, SRGB_THRESHOLD));
    const int i = (int)(bits >> SRGB_LUT_SHIFT) - SRGB_LUT_BASE;
    const float f = (float)(bits & ((1u << SRGB_LUT_SHIFT) - 1u)) * (1.0f / (float)(1u << SRGB_LUT_SHIFT));
    const float curve = mad(f, SRGB_LUT[i + 1] - SRGB_LUT[i], SRGB_LUT[i]);
    return (v <= SRGB_THRESHOLD) ? SRGB_SLOPE * v : curve;
}

/* quantize16: an encoded value in [0, 1] to the nearest 16-bit code. */
inline ushort quantize16(const float v)
{
    return (ushort)(clamp(v, 0.0f, 1.0f) * 65535.0f + 0.5f);
}
