/* The masked guided filter shared by both LMS demosaics (He et al.'s guided filter with box windows of
 * radius r, statistics over the pixels of one CFA channel); NumPy twins of the same names and the host
 * side in clisp/modules/common/guided_filter.py. Two kernels, run in this order:
 *   gf_ab_strip (the NumPy gf_row_moments, then gf_coefficients) -> gf_apply_strip (box_rows of a, b,
 *   then gf_apply).
 *
 * Defines from the host, the same for both kernels (a fit builds one program and runs both of its
 * kernels): GF_R (the radius r); GF_STRIP and GF_APPLY_STRIP (the output rows per work-item of
 * gf_ab_strip and gf_apply_strip); GF_MASK (the pixels of the statistics: 0 every pixel, 1 the M
 * sites, 2 the S sites, 3 the M and S pair); GF_LEVEL_GUIDE (1: the noise term of eps at the level mu_I, 0: at
 * mu_v); L_PAR, S_Y, S_D (the LMS CFA in closed form, at_l and at_s in common.h; the CFA phase is folded
 * into the image coordinates (oy, ox) by lattice_shift). Mask and level are compile-time so that the
 * selections fold away (as kernel arguments they cost the row-moment step 30% and the coefficients 10%).
 *
 * Geometry: the filter runs on an "own" window of h x w pixels and returns its (h - 4r) x (w - 4r)
 * centre. Kernel outputs are planar out_w x out_h images; the guide (plane from element g_base) and
 * the target v live on windows larger than the own window by g_off, v_off on every side; (oy, ox) are
 * the image coordinates of own-window pixel (0, 0). Statistics are centred on the guide value at the
 * output pixel, which keeps var = E[d^2] - E[d]^2 free of float32 cancellation: both terms are small
 * where the guide is flat, where uncentred E[I^2] - E[I]^2 would lose ~1e-8 against an eps of 1e-4.
 *
 * No kernel checks bounds: the host launches whole work-groups only and covers a ragged right or
 * bottom edge by shifting the last launch inward (runtime.launch_exact); bodies are branch-free. */

#include "guided.h"

inline float max_f(const float a, const float b) { return a > b ? a : b; }

/* ---- Fused strip kernels (what enqueue_guided_filter runs): the same sums in the same order as the
 * NumPy steps gf_row_moments, gf_coefficients, box_rows, gf_apply, without a 5-plane row-moment image
 * and 2-plane row sums of a, b going through global memory (with four step kernels, since removed,
 * those planes' traffic was most of the filter's time on PoCL).
 * One work-item computes GF_STRIP consecutive output rows of one column: a fully unrolled loop over
 * the GF_STRIP + 2r rows the strip needs, each row's sums along x kept in private registers and summed
 * along y as soon as the 2r + 1 rows of an output are there. Strip rows start at
 * min(gid1 * GF_STRIP, out_h - GF_STRIP): a ragged last strip is shifted up and recomputes identical
 * rows (out_h >= GF_STRIP, host-checked). The CFA mask is taken from a 4 x 4 table of the work-item's
 * phases (the lattice repeats every 4 px along x and y), built once per work-item: no integer work
 * per tap. */

#define GF_T (2 * GF_R + 1)
#define GF_NR (GF_STRIP + 2 * GF_R)

/* gf_ab_strip: the NumPy gf_row_moments then gf_coefficients (a, b; planes of out_w x out_h, out_w = w - 2r,
 * out_h = h - 2r), over the own window h x w (see Geometry above). Output (y, x) <-> own-window pixel
 * (y + r, x + r). Halo: reads +-r along x and y.
 * GF_MASK 3: the two fits of M at S in one pass (they share guide and target): fit 0 over the M sites
 * (planes a, b; eps noise shot, floor_), fit 1 over the S sites (planes 2, 3; shot2, floor2); chi_rows
 * then holds the M table followed by the S table. */
#define GF_FITS (GF_MASK == 3 ? 2 : 1)
__kernel void gf_ab_strip(__global const float *restrict guide, __global const float *restrict v, __global float *restrict ab,
                          __global const float *restrict chi_rows, const int chi_w, const int g_base, const int g_w,
                          const int g_off, const int v_w, const int v_off, const int out_w, const int out_h,
                          const int oy, const int ox, const float eps0, const float shot, const float floor_,
                          const float shot2, const float floor2)
{
    const int x = inward_id(0, out_w - 1);                 /* one command: common.h */
    const int y_s = inward_id(1, (out_h - 1) / GF_STRIP) * GF_STRIP, y0 = y_s < out_h - GF_STRIP ? y_s : out_h - GF_STRIP;
    float rn[GF_FITS][GF_NR], r1[GF_FITS][GF_NR], r2[GF_FITS][GF_NR], rv[GF_FITS][GF_NR], rdv[GF_FITS][GF_NR];
    float rc[GF_NR];
    const int plane = out_w * out_h;
    const int table = 2 * (4 + GF_NR) * chi_w;                 /* one fit's mask and count table */
    #pragma unroll
    for (int i = 0; i < GF_NR; ++i) {
        __global const float *gc = guide + g_base + (y0 + i + g_off) * g_w + x + GF_R + g_off;
        __global const float *vc = v + (y0 + i + v_off) * v_w + x + GF_R + v_off;
        __global const float *mrow = chi_rows + (((y0 + oy) & 3) + i) * chi_w + x + GF_R;
        const float c = gc[0];
        float n[GF_FITS], s1[GF_FITS], s2[GF_FITS], sv[GF_FITS], sdv[GF_FITS];
        #pragma unroll
        for (int f = 0; f < GF_FITS; ++f) {
            n[f] = GF_MASK == 0 ? (float)GF_T : mrow[f * table + (4 + GF_NR) * chi_w];   /* the row's count */
            s1[f] = s2[f] = sv[f] = sdv[f] = 0.0f;
        }
        #pragma unroll
        for (int k = -GF_R; k <= GF_R; ++k) {
            const float d = gc[k] - c, vv = vc[k];
            #pragma unroll
            for (int f = 0; f < GF_FITS; ++f) {
                const float chi = GF_MASK == 0 ? 1.0f : mrow[f * table + k];
                const float dk = chi * d;
                const float vk = chi != 0.0f ? vv : 0.0f;   /* not chi * v: PoCL's SLP pass pairs it with
                                                               dk and the work-item loop stays scalar */
                s1[f] += dk;
                s2[f] += dk * dk;
                sv[f] += vk;
                sdv[f] += dk * vk;
            }
        }
        rc[i] = c;
        #pragma unroll
        for (int f = 0; f < GF_FITS; ++f) {
            rn[f][i] = n[f]; r1[f][i] = s1[f]; r2[f][i] = s2[f]; rv[f][i] = sv[f]; rdv[f][i] = sdv[f];
        }
        if (i >= 2 * GF_R) {                                   /* resolved at compile time */
            const int o = i - 2 * GF_R;                        /* output row y0 + o, centre row o + r */
            const float cc = rc[o + GF_R];
            const int idx = (y0 + o) * out_w + x;
            #pragma unroll
            for (int f = 0; f < GF_FITS; ++f) {
                /* the rows' sums moved to the centre row's guide value; v stays uncentred (dy = 0) */
                gf_moments t = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
                #pragma unroll
                for (int j = o; j <= i; ++j)
                    gf_add_moved(&t, rn[f][j], r1[f][j], rv[f][j], r2[f][j], 0.0f, rdv[f][j], rc[j] - cc, 0.0f);
                float mean_d, mu_v, var, var_v, cov;
                gf_centred_stats(&t, 1.0f / t.n, &mean_d, &mu_v, &var, &var_v, &cov);
                const float mu_i = cc + mean_d;
                const float level = GF_LEVEL_GUIDE ? mu_i : mu_v;
                const float a = cov / (var + eps0 + (f == 0 ? shot : shot2) * max_f(level, 0.0f)
                                       + (f == 0 ? floor_ : floor2));
                ab[2 * f * plane + idx] = a;
                ab[(2 * f + 1) * plane + idx] = mu_v - a * mu_i;
            }
        }
    }
}

/* gf_apply_strip: box_rows of a, b then gf_apply: q = mean(a) I + mean(b) over the (2r+1)^2 windows
 * covering the pixel; ab: planes a, b of ab_w x ab_h (gf_ab_strip's output); q (ab_h - 2r) x
 * (ab_w - 2r) = out_h x out_w, written from element d_base of dst. Output (y, x) <-> ab (y + r, x + r),
 * the own window's (y + 2r, x + 2r), the guide's (y + 2r + g_off, x + 2r + g_off). Halo: reads
 * +2r along x and y of ab. GF_MASK 3 (two fits): planes 2, 3 of ab give the second q, written from
 * element d_base2 of dst2 (other masks: one fit). Strips of GF_APPLY_STRIP rows (two sums per row
 * leave room for longer strips than gf_ab_strip's). */
#define GF_APPLY_NR (GF_APPLY_STRIP + 2 * GF_R)
__kernel void gf_apply_strip(__global const float *restrict ab, __global const float *restrict guide, __global float *restrict dst,
                             __global float *restrict dst2, const int ab_w, const int ab_h, const int g_base,
                             const int g_w, const int g_off, const int out_w, const int out_h, const int d_base,
                             const int d_base2)
{
    const int x = inward_id(0, out_w - 1);                 /* one command: common.h */
    const int y_s = inward_id(1, (out_h - 1) / GF_APPLY_STRIP) * GF_APPLY_STRIP;
    const int y0 = y_s < out_h - GF_APPLY_STRIP ? y_s : out_h - GF_APPLY_STRIP;
    const int plane = ab_w * ab_h;
    const float inv = 1.0f / (float)((2 * GF_R + 1) * (2 * GF_R + 1));
    float ra[GF_FITS][GF_APPLY_NR], rb[GF_FITS][GF_APPLY_NR];
    #pragma unroll
    for (int i = 0; i < GF_APPLY_NR; ++i) {
        __global const float *rowp = ab + (y0 + i) * ab_w + x;
        #pragma unroll
        for (int f = 0; f < GF_FITS; ++f) {
            float sa = 0.0f, sb = 0.0f;
            #pragma unroll
            for (int k = 0; k <= 2 * GF_R; ++k) {
                sa += rowp[2 * f * plane + k];
                sb += rowp[(2 * f + 1) * plane + k];
            }
            ra[f][i] = sa;
            rb[f][i] = sb;
        }
        if (i >= 2 * GF_R) {                                   /* resolved at compile time */
            const int o = i - 2 * GF_R;
            const float g = guide[g_base + (y0 + o + 2 * GF_R + g_off) * g_w + x + 2 * GF_R + g_off];
            #pragma unroll
            for (int f = 0; f < GF_FITS; ++f) {
                float ta = 0.0f, tb = 0.0f;
                #pragma unroll
                for (int j = o; j <= i; ++j) {
                    ta += ra[f][j];
                    tb += rb[f][j];
                }
                if (f == 0)
                    dst[d_base + (y0 + o) * out_w + x] = (ta * g + tb) * inv;
                else
                    dst2[d_base2 + (y0 + o) * out_w + x] = (ta * g + tb) * inv;
            }
        }
    }
}
