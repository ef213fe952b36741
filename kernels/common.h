/* Helpers shared by every kernel file; the runtime prepends this text to each program.
 * Images are planar float32: plane c of an H x W image starts at c * H * W.
 * CFA_PERIOD (define from the host) is the side of the CFA's repeating tile. */
#ifndef CFA_PERIOD
#define CFA_PERIOD 2
#endif

/* CFA channel of image pixel (y, x); y and x may be negative (padded borders). */
inline int cfa_channel(__constant const char *pattern, const int y, const int x)
{
    const int py = ((y % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD;
    const int px = ((x % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD;
    return pattern[py * CFA_PERIOD + px];
}
