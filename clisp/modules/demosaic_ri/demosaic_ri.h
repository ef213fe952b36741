/* demosaic_ri.h: what the RI demosaic's two programs share (demosaic_ri.cl, demosaic_ri_chroma_fit.cl):
 * the mosaic read in 8-bit units and ARI's weighted fit. Needs RAW_T, RI_SCALE, RI_RMSE_FLOOR. */

/* The mosaic v at index i in 8-bit units (RI_SCALE 255). */
#define RAW(v, i) ((float)(v)[i] * RI_SCALE)

/* ARI's weighted fit of one window from its centred statistics: r = (a w, b w, w) with
 * b = mean_y - a mean_x, w = 1 / max(sqrt(max(a^2 var_x - 2 a cov + var_y, 0)), RI_RMSE_FLOOR). */
__attribute__((always_inline)) inline void ri_weighted_fit(const float a, const float mean_x, const float mean_y,
                                                           const float var_x, const float var_y, const float cov,
                                                           float *aw, float *bw, float *wt)
{
    const float b = mean_y - a * mean_x;
    const float mse = a * a * var_x - 2.0f * a * cov + var_y;
    const float rmse = __builtin_sqrtf(mse > 0.0f ? mse : 0.0f);
    const float w = 1.0f / (rmse > RI_RMSE_FLOOR ? rmse : RI_RMSE_FLOOR);
    *aw = a * w;
    *bw = b * w;
    *wt = w;
}
