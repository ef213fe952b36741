/* Gain terms and the smooth gain grid, shared by sensor.cl and sensor_shade.cl
 * (clisp/modules/sensor/stage.py: GainTerms, SmoothGain). */

/* One packed gain term (stage.GainTerms.pack): kind 1 GainMap, 2 FixVignetteRadial. */
#define T_KIND 0
#define T_LIST 1
#define T_AREA 2          /* t, l, b, r in mosaic coordinates; b <= t: every pixel */
#define T_PITCH 6         /* row pitch, column pitch */
#define T_ORIGIN 8        /* the opcode image's (0, 0) in mosaic coordinates */
#define T_INV 10          /* 1 / H, 1 / W of the opcode image */
#define T_POINTS 12       /* map points v, h */
#define T_INV_SPACING 14  /* 1 / spacing v, h */
#define T_MAP_ORIGIN 16   /* map origin v, h (relative) */
#define T_OFFSET 18       /* first gain of the map in maps[] */
#define T_K 12            /* radial: k0 .. k4 */
#define T_CENTER 17       /* radial: centre y, x (mosaic coordinates of the pixel-centre origin) */
#define T_INV_R2 19       /* radial: 1 / squared distance to the farthest corner */

/* term_gain: the gain of one term at image pixel (y, x): a GainMap's bilinear map (clamped index,
 * relative pixel centres, as the DNG SDK) or the radial polynomial; 1 where the term's area or pitch
 * leaves the pixel out. */
inline float term_gain(__constant const float *t, __global const float *maps, const int y, const int x)
{
    if (t[T_KIND] == 2.0f) {
        const float dy = (float)y + 0.5f - t[T_CENTER], dx = (float)x + 0.5f - t[T_CENTER + 1];
        const float r2 = (dy * dy + dx * dx) * t[T_INV_R2];
        float s = 0.0f;
        for (int i = 4; i >= 0; i--)
            s = r2 * (t[T_K + i] + s);
        return 1.0f + s;
    }
    const int top = (int)t[T_AREA], left = (int)t[T_AREA + 1], bottom = (int)t[T_AREA + 2], right = (int)t[T_AREA + 3];
    if (bottom > top) {
        const int rp = (int)t[T_PITCH], cp = (int)t[T_PITCH + 1];
        if (y < top || y >= bottom || x < left || x >= right || (y - top) % rp != 0 || (x - left) % cp != 0)
            return 1.0f;
    }
    const int pv = (int)t[T_POINTS], ph = (int)t[T_POINTS + 1];
    float v = (((float)(y - (int)t[T_ORIGIN]) + 0.5f) * t[T_INV] - t[T_MAP_ORIGIN]) * t[T_INV_SPACING];
    float h = (((float)(x - (int)t[T_ORIGIN + 1]) + 0.5f) * t[T_INV + 1] - t[T_MAP_ORIGIN + 1]) * t[T_INV_SPACING + 1];
    v = clamp(v, 0.0f, (float)(pv - 1));
    h = clamp(h, 0.0f, (float)(ph - 1));
    const int i0 = min((int)v, max(pv - 2, 0)), j0 = min((int)h, max(ph - 2, 0));
    const int i1 = min(i0 + 1, pv - 1), j1 = min(j0 + 1, ph - 1);
    const float fv = v - (float)i0, fh = h - (float)j0;
    __global const float *m = maps + (int)t[T_OFFSET];
    const float top_g = m[i0 * ph + j0] * (1.0f - fh) + m[i0 * ph + j1] * fh;
    const float bot_g = m[i1 * ph + j0] * (1.0f - fh) + m[i1 * ph + j1] * fh;
    return top_g * (1.0f - fv) + bot_g * fv;
}

#ifdef SC_TERMS
/* list_gain: the product of the terms of OpcodeList ``list`` at image pixel (y, x). */
inline float list_gain(__constant const float *terms, __global const float *maps, const int list, const int y,
                       const int x)
{
    float g = 1.0f;
    for (int i = 0; i < SC_TERMS; i++) {
        __constant const float *t = terms + i * SC_TERM_SIZE;
        if ((int)t[T_LIST] == list)
            g *= term_gain(t, maps, y, x);
    }
    return g;
}
#endif

/* grid_gain: the smooth gain G of channel c at image pixel (y, x): bilinear on nodes every ``cell``
 * pixels (node (i, j) at pixel (i cell, j cell)), clamped at the grid's edges. */
inline float grid_gain(__global const float *grid, const int gh, const int gw, const float inv_cell, const int c,
                       const float y, const float x)
{
    const float gy = clamp(y * inv_cell, 0.0f, (float)(gh - 1));
    const float gx = clamp(x * inv_cell, 0.0f, (float)(gw - 1));
    const int i0 = min((int)gy, max(gh - 2, 0)), j0 = min((int)gx, max(gw - 2, 0));
    const int i1 = min(i0 + 1, gh - 1), j1 = min(j0 + 1, gw - 1);
    const float fy = gy - (float)i0, fx = gx - (float)j0;
    __global const float *g = grid + c * gh * gw;
    return (g[i0 * gw + j0] * (1.0f - fx) + g[i0 * gw + j1] * fx) * (1.0f - fy)
         + (g[i1 * gw + j0] * (1.0f - fx) + g[i1 * gw + j1] * fx) * fy;
}

