/* The light field applied to a frame at its full resolution (relight.engine.field): the one pass
 * the per-frame path makes over the frame's pixels, in the frame's own codes.
 *
 * The field is a grid (gh, gw) of 32 floats: two affine maps of the frame's codes v = (c0, c1,
 * c2) - (Y', Cb, Cr) for planes, (R', G', B') for an RGB frame - each three rows of 4,
 *     out_c = m_c0 v0 + m_c1 v1 + m_c2 v2 + m_c3,
 * the tangent (the cell's change linearised at its colour) and the chord (through black and the
 * same point), then the share of the cell the change covers (0: nothing changes there), the
 * knee in the frame's codes and four zeros. A pixel takes the tangent where it is as bright as its
 * cell's knee (compositor.KNEE_GAP codes below its colour) or brighter, the chord below - so what is much
 * darker than its cell (glasses' rims, pupils, a nostril) keeps its darkness in proportion
 * instead of being lifted with the cell (a cell whose whole area is in a shadow the change fills
 * is lifted: its pixels are near its colour). A
 * frame pixel at (X, Y) reads the grid at ((X + 0.5) sx - 0.5 - gox, (Y + 0.5) sy - 0.5 - goy)
 * (sx, sy: cells per frame pixel; gox, goy: the grid's first cell in those units), bilinear, the
 * grid's edge cells carried on beyond it; a pixel whose four cells cover nothing keeps its bytes.
 *
 * field_rgb: (H, W, 3) uchar sRGB, in place over a box, a work item a pixel; per channel, the
 *   chord where the channel is below the cell's knee (blended over KNEE_RAMP codes: ``ramp``).
 * field_planes: 8-bit Y'CbCr planes, chroma subsampled by 2 across and by cy = 1 or 2 down (4:2:2
 *   or 4:2:0), over a box of whole chroma samples - the luma in place, the chroma read from (up,
 *   vp) and written to (uo, vo): its neighbours are read - a work item a chroma sample: the
 *   sample's cells read at its centre, its luma pixels each mapped with their own chroma (bilinear
 *   between the sample and its neighbours, as a conversion to RGB reads it; the
 *   chord where the pixel's luma is below the cell's knee, blended), the chroma with the mean of its
 *   luma pixels (by the chord where that mean is below the knee, blended), each rounded to the nearest
 *   code.
 * Plain scalar code (no vector types, no builtins): PoCL 3.0 vectorises work items only then.
 */

inline int ifl(float x) { int t = (int)x; return t - (((float)t > x) ? 1 : 0); }
inline int icl(int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); }
inline uchar code8(float v) { return (uchar)(v < 0.0f ? 0.0f : (v > 255.0f ? 255.0f : v + 0.5f)); }
/* The chord's share of a value v (a code) against its cell's knee: 0 at and above knee + KNEE_RAMP / 2,
   1 at and below knee - KNEE_RAMP / 2 (a hard switch flips with the sensor's noise). */
inline float ramp(float v, float knee)
{
    float a = (knee - v) * (1.0f / KNEE_RAMP) + 0.5f;
    return a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
}

/* The bilinear taps of grid position (gx, gy): the four cells' offsets (floats) and weights;
   returns their cover (0: nothing changes here). */
inline float taps(__global const float *grid, int gw, int gh, float gx, float gy, int *o, float *w)
{
    int x0 = ifl(gx), y0 = ifl(gy);
    float ax = gx - (float)x0, ay = gy - (float)y0;
    int xa = icl(x0, 0, gw - 1), xb = icl(x0 + 1, 0, gw - 1), ya = icl(y0, 0, gh - 1), yb = icl(y0 + 1, 0, gh - 1);
    o[0] = 32 * (ya * gw + xa);
    o[1] = 32 * (ya * gw + xb);
    o[2] = 32 * (yb * gw + xa);
    o[3] = 32 * (yb * gw + xb);
    w[0] = (1.0f - ax) * (1.0f - ay);
    w[1] = ax * (1.0f - ay);
    w[2] = (1.0f - ax) * ay;
    w[3] = ax * ay;
    return grid[o[0] + 24] + grid[o[1] + 24] + grid[o[2] + 24] + grid[o[3] + 24];
}

inline float coef(__global const float *grid, const int *o, const float *w, int k)
{
    return w[0] * grid[o[0] + k] + w[1] * grid[o[1] + k] + w[2] * grid[o[2] + k] + w[3] * grid[o[3] + k];
}

__kernel void field_rgb(
    __global uchar *img, int img_w, int bx0, int by0, int bw, int bh,
    __global const float *grid, int gw, int gh, float sx, float sy, float gox, float goy)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= bw || y >= bh)
        return;
    int i = bx0 + x, j = by0 + y;
    int o[4];
    float w[4];
    if (!(taps(grid, gw, gh, ((float)i + 0.5f) * sx - 0.5f - gox, ((float)j + 0.5f) * sy - 0.5f - goy, o, w) > 0.0f))
        return;
    size_t p = 3 * ((size_t)j * img_w + i);
    float r = (float)img[p], g = (float)img[p + 1], b = (float)img[p + 2];
    for (int c = 0; c < 3; ++c) {
        float t = coef(grid, o, w, 4 * c) * r + coef(grid, o, w, 4 * c + 1) * g + coef(grid, o, w, 4 * c + 2) * b
                  + coef(grid, o, w, 4 * c + 3);
        float d = coef(grid, o, w, 12 + 4 * c) * r + coef(grid, o, w, 13 + 4 * c) * g
                  + coef(grid, o, w, 14 + 4 * c) * b + coef(grid, o, w, 15 + 4 * c);
        img[p + c] = code8(t + ramp((float)img[p + c], coef(grid, o, w, 25 + c)) * (d - t));
    }
}

__kernel void field_planes(
    __global uchar *yp, int y_stride, __global const uchar *up, __global const uchar *vp,
    __global uchar *uo, __global uchar *vo, int c_stride, int c_w, int c_h, int cy,
    int cx0, int cy0, int cw, int ch,                   /* the box in chroma samples */
    __global const float *grid, int gw, int gh, float sx, float sy, float gox, float goy)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= cw || y >= ch)
        return;
    int ci = cx0 + x, cj = cy0 + y;
    float X = 2.0f * (float)ci + 0.5f, Y = (float)(cy * cj) + 0.5f * (float)(cy - 1);  /* the sample's centre */
    int o[4];
    float w[4];
    if (!(taps(grid, gw, gh, (X + 0.5f) * sx - 0.5f - gox, (Y + 0.5f) * sy - 0.5f - goy, o, w) > 0.0f))
        return;
    size_t co = (size_t)cj * c_stride + ci;
    float cb = (float)up[co], cr = (float)vp[co];
    float gain_t = coef(grid, o, w, 0), gain_d = coef(grid, o, w, 12), cell = coef(grid, o, w, 25);
    size_t lo = (size_t)(cy * cj) * y_stride + 2 * ci;
    /* each luma pixel's own chroma: bilinear between this sample and its neighbours (the samples
       centred on their 2 x cy blocks), as the conversion to RGB would read it - edges replicated */
    int cl_ = ci > 0 ? ci - 1 : ci, cr_ = ci + 1 < c_w ? ci + 1 : ci;
    int cu_ = cj > 0 ? cj - 1 : cj, cd_ = cj + 1 < c_h ? cj + 1 : cj;
    float sum = 0.0f;
    float hy = cy == 2 ? 0.25f : 0.0f;  /* the neighbour's share down the rows (4:2:0), across: 0.25 */
    for (int k = 0; k < 2 * cy; ++k) {
        int dx = (k & 1) ? cr_ : cl_, dy = cy == 2 ? ((k >> 1) ? cd_ : cu_) : cj;
        size_t sx_ = (size_t)cj * c_stride + dx, sy_ = (size_t)dy * c_stride + ci, sxy = (size_t)dy * c_stride + dx;
        float pb = (1.0f - hy) * (0.75f * cb + 0.25f * (float)up[sx_]) + hy * (0.75f * (float)up[sy_] + 0.25f * (float)up[sxy]);
        float pr = (1.0f - hy) * (0.75f * cr + 0.25f * (float)vp[sx_]) + hy * (0.75f * (float)vp[sy_] + 0.25f * (float)vp[sxy]);
        size_t p = lo + (size_t)(k >> 1) * y_stride + (k & 1);
        float l = (float)yp[p];
        sum += l;
        float t = gain_t * l + coef(grid, o, w, 1) * pb + coef(grid, o, w, 2) * pr + coef(grid, o, w, 3);
        float d = gain_d * l + coef(grid, o, w, 13) * pb + coef(grid, o, w, 14) * pr + coef(grid, o, w, 15);
        yp[p] = code8(t + ramp(l, cell) * (d - t));
    }
    float lm = sum / (float)(2 * cy);
    float a = ramp(lm, cell);  /* the chord's share at the sample's mean luma */
    float ut = coef(grid, o, w, 4) * lm + coef(grid, o, w, 5) * cb + coef(grid, o, w, 6) * cr + coef(grid, o, w, 7);
    float ud = coef(grid, o, w, 16) * lm + coef(grid, o, w, 17) * cb + coef(grid, o, w, 18) * cr + coef(grid, o, w, 19);
    float vt = coef(grid, o, w, 8) * lm + coef(grid, o, w, 9) * cb + coef(grid, o, w, 10) * cr + coef(grid, o, w, 11);
    float vd = coef(grid, o, w, 20) * lm + coef(grid, o, w, 21) * cb + coef(grid, o, w, 22) * cr + coef(grid, o, w, 23);
    uo[co] = code8(ut + a * (ud - ut));
    vo[co] = code8(vt + a * (vd - vt));
}
