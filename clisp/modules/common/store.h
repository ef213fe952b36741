/* store.h: the output element type and store of a stage that may end in the sRGB tone curve.
 * Defines from the host: ENCODE_SRGB (1: store the encoded value; the host then prepends
 * clisp/modules/colour/srgb.h, with encode_srgb and quantize16), QUANTIZE (1: as codes of CODE_BITS,
 * 16 (ushort) or 8 (uchar); with ENCODE_SRGB only). Included by linear_filter.cl and half_size.cl. */
#if ENCODE_SRGB && QUANTIZE && CODE_BITS == 8
typedef uchar out_t;
#define STORE(v) quantize8(encode_srgb(v))
#elif ENCODE_SRGB && QUANTIZE
typedef ushort out_t;
#define STORE(v) quantize16(encode_srgb(v))
#elif ENCODE_SRGB
typedef float out_t;
#define STORE(v) encode_srgb(v)
#else
typedef float out_t;
#define STORE(v) (v)
#endif
