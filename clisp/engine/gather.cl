/* A tile's window gathered from the whole mosaic on the device (the engine's streaming, when the
 * whole mosaic is resident). Defines from the host: RAW_T (the sample type), CFA_PERIOD, MIRROR_X. */

#include "mirror.h"

/* gather_window: dst (h x dst_w) = the window at (y0, x0) of the whole src_h x src_w mosaic src,
 * rows and columns outside the mosaic CFA-mirrored (cfa_mirror with CFA_PERIOD), as
 * tiling.gather_window does on the host. Halo 0. Rows are uniform per work-item row; columns are
 * mirrored only with MIRROR_X (the launches over the window's columns outside the mosaic): the
 * launch over the inside columns reads consecutive samples with no bounds checks (launch_exact),
 * so PoCL vectorises it. Every launch covers exactly its columns (global offset, no checks). */
__kernel void gather_window(__global const RAW_T *restrict src, __global RAW_T *restrict dst,
                            const int src_h, const int src_w, const int y0, const int x0, const int dst_w)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int sy = cfa_mirror(y0 + y, src_h, CFA_PERIOD);
#if MIRROR_X
    const int sx = cfa_mirror(x0 + x, src_w, CFA_PERIOD);
#else
    const int sx = x0 + x;
#endif
    dst[y * dst_w + x] = src[sy * src_w + sx];
}
