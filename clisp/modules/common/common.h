/* Helpers shared by every kernel file; the runtime prepends this text to each program.
 * Images are planar float32: plane c of an H x W image starts at c * H * W.
 * CFA_PERIOD (define from the host, in the programs that read a CFA pattern) is the side of the
 * CFA's repeating tile. */

#ifdef CFA_PERIOD
/* CFA channel of image pixel (y, x); y and x may be negative (padded borders). */
inline int cfa_channel(__constant const char *pattern, const int y, const int x)
{
    const int py = ((y % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD;
    const int px = ((x % CFA_PERIOD) + CFA_PERIOD) % CFA_PERIOD;
    return pattern[py * CFA_PERIOD + px];
}
#endif

#ifdef L_PAR
/* LMS CFA membership of image pixel (y, x) in closed form, for programs built with the defines
 * L_PAR, S_Y, S_D (clisp.modules.common.lms.LATTICE; the CFA phase is folded into the image
 * coordinates by lattice_shift): L iff x + y + L_PAR is even; S iff y + S_Y is even and x - y + S_D
 * is a multiple of 4; M otherwise. y and x may be negative (& is exact in two's complement). */
inline int at_l(const int y, const int x) { return ((x + y + L_PAR) & 1) == 0; }
inline int at_s(const int y, const int x) { return ((y + S_Y) & 1) == 0 && ((x - y + S_D) & 3) == 0; }
#endif

/* The output coordinate along dimension dim of a kernel launched with whole work-groups past the
 * edge (clisp.engine.runtime.launch_exact, inward=True): the global id, the last work-group shifted
 * inward to end at last (its work-items past the edge recompute outputs of the group before and
 * store the values it stores: Halide's ShiftInwards tail, within one launch). Local id plus a value
 * uniform over the work-group, so the loads of neighbouring work-items stay consecutive and PoCL
 * vectorises them (a per-item min(id, last) made them gathers: RI 2x slower). Needs at least one
 * work-group of outputs (launch_exact's group rule). */
inline int inward_id(const uint dim, const int last)
{
    const int size = (int)get_local_size(dim);
    return (int)get_local_id(dim) + min((int)(get_global_offset(dim) + get_group_id(dim) * size), last + 1 - size);
}
