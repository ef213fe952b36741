/* The box filter's sums, the one definition (clisp/modules/common/box.py, box_sums, is their float64
 * reference): box.cl's kernels run them at every output pixel; a kernel that needs box sums only at
 * some sites of its own (the highlight stage's cells next to clipped pixels) calls them there.
 * Every sum runs in order from 0.0f, so a caller's results do not depend on where it is computed. */

#ifdef BOX_R
/* box_sum: sum_{k=0..2 BOX_R} s[k stride], BOX_R a define (a compile-time trip count: the loop
 * unrolls fully and PoCL vectorises the calling kernel across work-items; as a runtime argument the
 * box kernels ran 3x slower). */
__attribute__((always_inline)) inline float box_sum(__global const float *restrict s, const int stride)
{
    float acc = 0.0f;
#pragma unroll
    for (int k = 0; k <= 2 * BOX_R; ++k)
        acc += s[k * stride];
    return acc;
}
#endif

/* box_sum_rect: the sum of the rectangle rows j0..j1, columns i0..i1 (inclusive) of a plane of row
 * pitch w, row-major; a box clamped to an image's edge counts the cells outside as 0. */
__attribute__((always_inline)) inline float box_sum_rect(__global const float *restrict p, const int w, const int i0,
                                                         const int i1, const int j0, const int j1)
{
    float acc = 0.0f;
    for (int j = j0; j <= j1; ++j)
        for (int i = i0; i <= i1; ++i)
            acc += p[j * w + i];
    return acc;
}
