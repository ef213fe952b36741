/* The guided filter's window statistics (He, Sun, Tang, "Guided image filtering", TPAMI 2013): the
 * one definition of its maths, included by every kernel that fits a guided filter
 * (clisp/modules/common/guided_filter.cl for both LMS demosaics, clisp/modules/demosaic_ari/
 * demosaic_ari.cl for ARI's weighted line fits). The kernels differ in schedule only (strips of
 * rows, or lines along a direction) and in their masks, weights and regularisers.
 *
 * Window sums are taken about a centre (the guide value cx and target value cy at the output pixel),
 * so that var = E[d^2] - E[d]^2 cancels at the scale of the local spread, not of the values: float32
 * sums of uncentred 8-bit data lose ~4e-3 of a variance to cancellation. A line's sums, taken about
 * its own centre, move to the window's centre exactly (gf_add_moved). A target whose centre is
 * 0.0f for every line (dy = 0) is an uncentred target. */

/* Sums over a window of d = x - cx (guide) and e = y - cy (target): n = sum of the weights (or mask),
 * s1x = sum d, s1y = sum e, s2x = sum d^2, s2y = sum e^2, sxy = sum d e. */
typedef struct { float n, s1x, s1y, s2x, s2y, sxy; } gf_moments;

/* gf_add_moved: add to m the sums of one line (nj, sd, se, sdd, see, sde: its n, s1x, s1y, s2x, s2y,
 * sxy about its own centre (cx_j, cy_j)), moved to m's centre (cx, cy) with dx = cx_j - cx,
 * dy = cy_j - cy: sum (d + dx) = sd + nj dx, sum (d + dx)^2 = sdd + dx (2 sd + nj dx),
 * sum (d + dx)(e + dy) = sde + dx se + dy sd + nj dx dy (exact algebra). */
__attribute__((always_inline)) inline void gf_add_moved(gf_moments *m, const float nj, const float sd, const float se,
                                                        const float sdd, const float see, const float sde,
                                                        const float dx, const float dy)
{
    m->n += nj;
    m->s1x += sd + nj * dx;
    m->s1y += se + nj * dy;
    m->s2x += sdd + dx * (2.0f * sd + nj * dx);
    m->s2y += see + dy * (2.0f * se + nj * dy);
    m->sxy += sde + dx * se + dy * sd + nj * dx * dy;
}

/* gf_centred_stats: from m and inv = 1 / count (the caller's count: n, or max(n, 1) for windows that
 * may be empty), the mean deviations md = E[d], me = E[e] and var_x = E[d^2] - md^2,
 * var_y = E[e^2] - me^2, cov = E[d e] - md me. The means themselves are cx + md, cy + me. */
__attribute__((always_inline)) inline void gf_centred_stats(const gf_moments *m, const float inv, float *md, float *me,
                                                            float *var_x, float *var_y, float *cov)
{
    *md = m->s1x * inv;
    *me = m->s1y * inv;
    *var_x = m->s2x * inv - *md * *md;
    *var_y = m->s2y * inv - *me * *me;
    *cov = m->sxy * inv - *md * *me;
}
