/* The light field applied to a frame at its full resolution (relight.engine.field): the one pass
 * the per-frame path makes over the frame's pixels, in the frame's own codes.
 *
 * The field is a grid (gh, gw) of 32 floats (8 float4): two affine maps of the frame's codes
 * v = (c0, c1, c2) - (Y', Cb, Cr) for planes, (R', G', B') for an RGB frame - each three rows of 4,
 *     out_c = m_c0 v0 + m_c1 v1 + m_c2 v2 + m_c3,
 * the tangent (the cell's change linearised at its colour) and the chord (through black and the
 * tangent at the knee), then (the share of the cell the change covers - 0: nothing changes there -,
 * the knee in the frame's codes) and four zeros. A pixel takes the tangent where it is as bright as
 * its cell's knee (compositor.KNEE_GAP codes below its colour) or brighter, the chord below,
 * blended over KNEE_RAMP codes - so what is much darker than its cell (glasses' rims, pupils, a
 * nostril) keeps its darkness in proportion instead of being lifted with the cell (a cell whose
 * whole area is in a shadow the change fills is lifted: its pixels are near its colour).
 *
 * A frame pixel at X reads the grid at (X + 0.5) / F - 0.5 - corner / F (F: frame pixels per cell;
 * corner: the grid's first cell's corner, even), bilinear, the grid's edge cells carried on beyond
 * it. A work item is a tile: the pixels (field_rgb) or chroma samples (field_planes) between four
 * cell centres - their four cells read once, the coefficients interpolated incrementally (the
 * weights of a tile's samples are fixed: F and the corner's parity fix them). A tile whose four
 * cells cover nothing keeps its bytes. F, and for the planes CY (chroma rows per luma row: 2 for
 * 4:2:0, 1 for 4:2:2), are build options; TX, TY, OX, OY the tile's samples and their first
 * weight's offset (relight.kernels.field_apply.tile_geometry).
 *
 * field_rgb: (H, W, 3) uchar sRGB, in place over a box; per channel the chord where the channel is
 *   below the cell's knee for it.
 * field_planes: 8-bit Y'CbCr planes, over a box of whole chroma samples - the luma in place, the
 *   chroma read from (up, vp) and written to (uo, vo): each luma pixel mapped with its sample's
 *   chroma, the chroma with the mean of the sample's luma pixels, each rounded to the nearest code.
 */

inline float4 clamp4(float4 v, float lo, float hi) { return v < lo ? (float4)(lo) : (v > hi ? (float4)(hi) : v); }
inline uchar code8(float v) { return (uchar)(v < 0.0f ? 0.0f : (v > 255.0f ? 255.0f : v + 0.5f)); }
inline int iclamp(int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* The chord's share of a value v (a code) against its cell's knee: 0 at and above knee + KNEE_RAMP / 2,
   1 at and below knee - KNEE_RAMP / 2 (a hard switch flips with the sensor's noise). */
inline float ramp(float v, float knee)
{
    float a = (knee - v) * (1.0f / KNEE_RAMP) + 0.5f;
    return a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
}

/* The tile's four cells as a bilinear patch: A + x B + y (C + x D) for each of the 7 float4 that
   are read (the 8th is zeros). */
#define CELLS                                                                                          \
    int xa = iclamp(a, 0, gw - 1), xb = iclamp(a + 1, 0, gw - 1);                                      \
    int ya = iclamp(b, 0, gh - 1), yb = iclamp(b + 1, 0, gh - 1);                                      \
    __global const float4 *g00 = grid + 8 * (ya * gw + xa), *g10 = grid + 8 * (ya * gw + xb);          \
    __global const float4 *g01 = grid + 8 * (yb * gw + xa), *g11 = grid + 8 * (yb * gw + xb);          \
    if (!(g00[6].x + g10[6].x + g01[6].x + g11[6].x > 0.0f))                                           \
        continue;
#define DEF(k) float4 A##k = g00[k], B##k = g10[k] - A##k, C##k = g01[k] - A##k, D##k = g11[k] - g10[k] - C##k;
#define ROW(k) float4 P##k = A##k + ay * C##k, Q##k = B##k + ay * D##k;
#define AT(k) float4 m##k = P##k + ax * Q##k;

__kernel void field_rgb(
    __global uchar *img, int img_w, int x0, int y0, int x1, int y1,   /* the box (pixels) */
    int ta0, int tb0, int nta, int ntb, int px0, int py0,              /* tiles: first, counts; tile 0's first pixel */
    __global const float4 *grid, int gw, int gh)
{
    int tb = get_global_id(1);
    if (tb >= ntb)
        return;
    for (int ta = get_global_id(0) * TILES; ta < (int)(get_global_id(0) + 1) * TILES && ta < nta; ++ta) {
        int a = ta0 + ta, b = tb0 + tb;
        CELLS
        DEF(0) DEF(1) DEF(2) DEF(3) DEF(4) DEF(5) DEF(6)
        for (int j = 0; j < TY; ++j) {
            int y = py0 + b * TY + j;
            if (y < y0 || y >= y1)
                continue;
            float ay = ((float)j + OY) * (1.0f / (float)TY);
            ROW(0) ROW(1) ROW(2) ROW(3) ROW(4) ROW(5) ROW(6)
            for (int i = 0; i < TX; ++i) {
                int x = px0 + a * TX + i;
                if (x < x0 || x >= x1)
                    continue;
                float ax = ((float)i + OX) * (1.0f / (float)TX);
                AT(0) AT(1) AT(2) AT(3) AT(4) AT(5) AT(6)
                size_t p = 3 * ((size_t)y * img_w + x);
                float4 v = (float4)((float)img[p], (float)img[p + 1], (float)img[p + 2], 1.0f);
#define DOT(m) ((m).x * v.x + (m).y * v.y + (m).z * v.z + (m).w)
                float4 t = (float4)(DOT(m0), DOT(m1), DOT(m2), 0.0f);
                float4 d = (float4)(DOT(m3), DOT(m4), DOT(m5), 0.0f);
                float4 w = (float4)(ramp(v.x, m6.y), ramp(v.y, m6.z), ramp(v.z, m6.w), 0.0f);
                float4 o = clamp4(t + w * (d - t), 0.0f, 255.0f) + 0.5f;
                img[p] = (uchar)o.x;
                img[p + 1] = (uchar)o.y;
                img[p + 2] = (uchar)o.z;
            }
        }
    }
}

__kernel void field_planes(
    __global uchar *yp, int y_stride, __global const uchar *up, __global const uchar *vp,
    __global uchar *uo, __global uchar *vo, int c_stride,
    int cx0, int cy0, int cx1, int cy1,                                /* the box in chroma samples */
    int ta0, int tb0, int nta, int ntb, int sx0, int sy0,              /* tiles: first, counts; tile 0's first sample */
    __global const float4 *grid, int gw, int gh)
{
    int tb = get_global_id(1);
    if (tb >= ntb)
        return;
    for (int ta = get_global_id(0) * TILES; ta < (int)(get_global_id(0) + 1) * TILES && ta < nta; ++ta) {
        int a = ta0 + ta, b = tb0 + tb;
        CELLS
        DEF(0) DEF(1) DEF(2) DEF(3) DEF(4) DEF(5) DEF(6)
        for (int j = 0; j < TY; ++j) {
            int cj = sy0 + b * TY + j;
            if (cj < cy0 || cj >= cy1)
                continue;
            float ay = ((float)j + OY) * (1.0f / (float)TY);
            ROW(0) ROW(1) ROW(2) ROW(3) ROW(4) ROW(5) ROW(6)
            for (int i = 0; i < TX; ++i) {
                int ci = sx0 + a * TX + i;
                if (ci < cx0 || ci >= cx1)
                    continue;
                float ax = ((float)i + OX) * (1.0f / (float)TX);
                AT(0) AT(1) AT(2) AT(3) AT(4) AT(5) AT(6)
                size_t co = (size_t)cj * c_stride + ci;
                float cb = (float)up[co], cr = (float)vp[co];
                float bt = m0.y * cb + m0.z * cr + m0.w, bd = m3.y * cb + m3.z * cr + m3.w;
                float knee = m6.y;
                size_t lo = (size_t)(CY * cj) * y_stride + 2 * ci;
#if CY == 2
                uchar2 r0 = vload2(0, yp + lo), r1 = vload2(0, yp + lo + y_stride);
                float4 l = (float4)((float)r0.x, (float)r0.y, (float)r1.x, (float)r1.y);
                float lm = 0.25f * (l.x + l.y + l.z + l.w);
#else
                uchar2 r0 = vload2(0, yp + lo);
                float4 l = (float4)((float)r0.x, (float)r0.y, (float)r0.x, (float)r0.y);
                float lm = 0.5f * (l.x + l.y);
#endif
                float4 t = m0.x * l + bt, d = m3.x * l + bd;
                float4 w = clamp4((knee - l) * (1.0f / KNEE_RAMP) + 0.5f, 0.0f, 1.0f);
                float4 o = clamp4(t + w * (d - t), 0.0f, 255.0f) + 0.5f;
                vstore2((uchar2)((uchar)o.x, (uchar)o.y), 0, yp + lo);
#if CY == 2
                vstore2((uchar2)((uchar)o.z, (uchar)o.w), 0, yp + lo + y_stride);
#endif
                float s = ramp(lm, knee);
                float ut = m1.x * lm + m1.y * cb + m1.z * cr + m1.w, ud = m4.x * lm + m4.y * cb + m4.z * cr + m4.w;
                float vt = m2.x * lm + m2.y * cb + m2.z * cr + m2.w, vd = m5.x * lm + m5.y * cb + m5.z * cr + m5.w;
                uo[co] = code8(ut + s * (ud - ut));
                vo[co] = code8(vt + s * (vd - vt));
            }
        }
    }
}
