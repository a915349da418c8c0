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
 * it. A tile is the pixels (field_rgb) or chroma samples (field_planes) between four cell centres:
 * the weights of its samples are fixed (F and the corner's parity fix them). field_rgb's work item
 * is a tile - its four cells read once, the coefficients interpolated incrementally. A tile whose
 * four cells cover nothing keeps its bytes. F, and for the planes CY (chroma rows per luma row: 2 for
 * 4:2:0, 1 for 4:2:2), are build options; TX, TY, OX, OY the tile's samples and their first
 * weight's offset (relight.kernels.field_apply.tile_geometry).
 *
 * field_rgb: (H, W, 3) uchar sRGB, in place over a box; per channel the chord where the channel is
 *   below the cell's knee for it.
 * field_planes: 8-bit Y'CbCr planes in place, over a box of whole chroma samples: each luma pixel
 *   mapped with its sample's chroma, the chroma with the mean of the sample's luma pixels, each
 *   rounded to the nearest code (its own layout of the grid and its work items: below).
 */

inline float4 clamp4(float4 v, float lo, float hi) { return v < lo ? (float4)(lo) : (v > hi ? (float4)(hi) : v); }
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

/* field_planes: a work item is a run of whole tiles along one chroma row - NT tiles of TX samples,
 * at most 8 samples (LANES) - computed as 8-wide vectors. It reads the grid as rows of each
 * coefficient (soa: (gh, 32, sw) floats, cell c of a row at c + pad, the edge cells carried on
 * beyond - relight.kernels.field_apply.soa_rows): the two grid rows interpolated along y, then
 * each lane takes its pair of cells by a shuffle along x. Clang's own vector built-ins only (PoCL
 * calls its library's - vload, convert, clamp - as functions: the loop is then scalar). Lanes
 * outside the box or past LANES, and samples whose four cells cover nothing, keep their bytes. */
typedef float float8u __attribute__((ext_vector_type(8), aligned(4)));
typedef uchar uchar8u __attribute__((ext_vector_type(8), aligned(1)));
typedef uchar uchar16u __attribute__((ext_vector_type(16), aligned(1)));
#define LD8F(p) (*(__global const float8u *)(p))
#define LD8B(p) __builtin_convertvector(*(__global const uchar8u *)(p), float8)
#define LD16B(p) __builtin_convertvector(*(__global const uchar16u *)(p), float16)
#define ST8B(v, p) (*(__global uchar8u *)(p) = __builtin_convertvector((v), uchar8))
#define ST16B(v, p) (*(__global uchar16u *)(p) = __builtin_convertvector((v), uchar16))
typedef uchar uchar4u __attribute__((ext_vector_type(4), aligned(1)));
typedef uchar uchar2u __attribute__((ext_vector_type(2), aligned(1)));
/* the first LANES chroma samples (n = LANES) or their 2 x LANES luma pixels (n = 2 LANES) of a
   vector stored, in whole pieces (a run of fewer than 8 samples must not touch its neighbour's) */
#define ST_FIRST8(b, p, n) do {                                                                     \
        if ((n) >= 4) *(__global uchar4u *)(p) = (b).s0123;                                          \
        if (((n) & 3) >= 2) *(__global uchar2u *)((p) + ((n) & 4)) = ((n) >= 4 ? (b).s45 : (b).s01); \
        if ((n) & 1) (p)[(n) - 1] = (b)[(n) - 1];                                                    \
    } while (0)
#define ST_FIRST16(b, p, n) do {                                                                    \
        *(__global uchar8u *)(p) = (b).s01234567;                                                    \
        uchar8 hi_ = (b).s89abcdef;                                                                  \
        ST_FIRST8(hi_, (p) + 8, (n) - 8);                                                            \
    } while (0)
#define NT (TX >= 8 ? 1 : 8 / TX)
#define LANES (NT * TX)
#define LO_IDX 0 / TX, 1 / TX, 2 / TX, 3 / TX, 4 / TX, 5 / TX, 6 / TX, 7 / TX
#define HI_IDX 0 / TX + 1, 1 / TX + 1, 2 / TX + 1, 3 / TX + 1, 4 / TX + 1, 5 / TX + 1, 6 / TX + 1, 7 / TX + 1
#define WX(L) (((float)((L) % TX) + OX) * (1.0f / (float)TX))

inline int fdiv(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
inline float8 ramp8(float8 v, float8 knee)
{
    float8 a = (knee - v) * (1.0f / KNEE_RAMP) + 0.5f;
    return a < 0.0f ? (float8)(0.0f) : (a > 1.0f ? (float8)(1.0f) : a);
}
inline float8 round8(float8 v) { return (v < 0.0f ? (float8)(0.0f) : (v > 255.0f ? (float8)(255.0f) : v)) + 0.5f; }

/* coefficient k (0-31) of the lanes: the two rows' cells interpolated along y, then along x */
#if TX == 1
#define YV(k, o) ({ float8 a_ = LD8F(ra + (k) * sw + (o)); a_ + ay * (LD8F(rb + (k) * sw + (o)) - a_); })
#define COEF(k) ({ float8 v_ = YV(k, 0), w_ = YV(k, 8); float8 lo_ = __builtin_shufflevector(v_, w_, LO_IDX); \
                   float8 hi_ = __builtin_shufflevector(v_, w_, HI_IDX); lo_ + wx * (hi_ - lo_); })
#define COVER(k) ({ float8 v_ = LD8F(ra + (k) * sw) + LD8F(rb + (k) * sw); \
                    float8 w_ = LD8F(ra + (k) * sw + 8) + LD8F(rb + (k) * sw + 8); \
                    __builtin_shufflevector(v_, w_, LO_IDX) + __builtin_shufflevector(v_, w_, HI_IDX); })
#else
#define COEF(k) ({ float8 a_ = LD8F(ra + (k) * sw); float8 v_ = a_ + ay * (LD8F(rb + (k) * sw) - a_); \
                   float8 lo_ = __builtin_shufflevector(v_, v_, LO_IDX); \
                   float8 hi_ = __builtin_shufflevector(v_, v_, HI_IDX); lo_ + wx * (hi_ - lo_); })
#define COVER(k) ({ float8 v_ = LD8F(ra + (k) * sw) + LD8F(rb + (k) * sw); \
                    __builtin_shufflevector(v_, v_, LO_IDX) + __builtin_shufflevector(v_, v_, HI_IDX); })
#endif

__kernel void field_planes(
    __global uchar *yp, int y_stride, __global uchar *up, __global uchar *vp, int c_stride,
    int cx0, int cy0, int cx1, int cy1,                                /* the box in chroma samples */
    int ta0, int nitems, int sx0, int sy0,                             /* first tile, items; tile 0's first sample */
    __global const float *soa, int gw, int gh, int sw, int pad)
{
    int g = get_global_id(0), rj = get_global_id(1);
    if (g >= nitems || cy0 + rj >= cy1)
        return;
    int cj = cy0 + rj;
    int a = ta0 + g * NT;                      /* the item's first tile: its first cell */
    int ci = sx0 + a * TX;                     /* its first sample */
    int b = fdiv(cj - sy0, TY);
    float ay = ((float)(cj - sy0 - b * TY) + OY) * (1.0f / (float)TY);
    int ya = iclamp(b, 0, gh - 1), yb = iclamp(b + 1, 0, gh - 1);
    /* (a run past the grid's ends reads its carried-on edge cells: pad >= 16) */
    int ac = iclamp(a, -pad, gw + pad - 16) + pad;
    __global const float *ra = soa + (size_t)ya * 32 * sw + ac, *rb = soa + (size_t)yb * 32 * sw + ac;
    const float8 wx = (float8)(WX(0), WX(1), WX(2), WX(3), WX(4), WX(5), WX(6), WX(7));
    int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    int8 in = (lane < LANES) & ((int8)(ci) + lane >= (int8)(cx0)) & ((int8)(ci) + lane < (int8)(cx1));
    int8 on = in & (COVER(24) > 0.0f);
    if (!(on.s0 | on.s1 | on.s2 | on.s3 | on.s4 | on.s5 | on.s6 | on.s7))
        return;
    /* whole vectors: the run inside the box and 8 samples inside the row (LANES of them stored) */
    int full = ci >= cx0 && ci + LANES <= cx1 && ci + 8 <= c_stride;
    size_t co = (size_t)cj * c_stride + ci;
    size_t lo = (size_t)(CY * cj) * y_stride + 2 * ci;
    float8 cb, cr;
    float16 r0, r1;
    if (full) {
        cb = LD8B(up + co);
        cr = LD8B(vp + co);
        r0 = LD16B(yp + lo);
#if CY == 2
        r1 = LD16B(yp + lo + y_stride);
#else
        r1 = r0;
#endif
    } else { /* the box's ends: each lane's own samples alone */
        float cbt[8], crt[8], l0t[16], l1t[16];
        for (int i = 0; i < 8; ++i) {
            int ok = i < LANES && ci + i >= cx0 && ci + i < cx1;
            cbt[i] = ok ? (float)up[co + i] : 0.0f;
            crt[i] = ok ? (float)vp[co + i] : 0.0f;
            l0t[2 * i] = ok ? (float)yp[lo + 2 * i] : 0.0f;
            l0t[2 * i + 1] = ok ? (float)yp[lo + 2 * i + 1] : 0.0f;
#if CY == 2
            l1t[2 * i] = ok ? (float)yp[lo + y_stride + 2 * i] : 0.0f;
            l1t[2 * i + 1] = ok ? (float)yp[lo + y_stride + 2 * i + 1] : 0.0f;
#else
            l1t[2 * i] = l0t[2 * i];
            l1t[2 * i + 1] = l0t[2 * i + 1];
#endif
        }
        cb = *(float8u *)cbt;
        cr = *(float8u *)crt;
        r0 = *(float16 *)l0t;
        r1 = *(float16 *)l1t;
    }
    float8 gt = COEF(0), bt = COEF(1) * cb + COEF(2) * cr + COEF(3);
    float8 gd = COEF(12), bd = COEF(13) * cb + COEF(14) * cr + COEF(15);
    float8 knee = COEF(25);
#define LUMA8(l) ({ float8 t_ = gt * (l) + bt, d_ = gd * (l) + bd; on ? round8(t_ + ramp8((l), knee) * (d_ - t_)) : (l); })
    float16 o0, o1;
    o0.even = LUMA8(r0.even);
    o0.odd = LUMA8(r0.odd);
#if CY == 2
    o1.even = LUMA8(r1.even);
    o1.odd = LUMA8(r1.odd);
    float8 lm = 0.25f * (r0.even + r0.odd + r1.even + r1.odd);
#else
    o1 = o0;
    float8 lm = 0.5f * (r0.even + r0.odd);
#endif
    float8 s = ramp8(lm, knee);
    float8 ut = COEF(4) * lm + COEF(5) * cb + COEF(6) * cr + COEF(7);
    float8 ud = COEF(16) * lm + COEF(17) * cb + COEF(18) * cr + COEF(19);
    float8 vt = COEF(8) * lm + COEF(9) * cb + COEF(10) * cr + COEF(11);
    float8 vd = COEF(20) * lm + COEF(21) * cb + COEF(22) * cr + COEF(23);
    float8 un = on ? round8(ut + s * (ud - ut)) : cb, vn = on ? round8(vt + s * (vd - vt)) : cr;
    if (full) {
#if LANES == 8
        ST16B(o0, yp + lo);
#if CY == 2
        ST16B(o1, yp + lo + y_stride);
#endif
        ST8B(un, up + co);
        ST8B(vn, vp + co);
#else
        uchar16 b0 = __builtin_convertvector(o0, uchar16);
        uchar8 bu = __builtin_convertvector(un, uchar8), bv = __builtin_convertvector(vn, uchar8);
        ST_FIRST16(b0, yp + lo, 2 * LANES);
#if CY == 2
        uchar16 b1 = __builtin_convertvector(o1, uchar16);
        ST_FIRST16(b1, yp + lo + y_stride, 2 * LANES);
#endif
        ST_FIRST8(bu, up + co, LANES);
        ST_FIRST8(bv, vp + co, LANES);
#endif
    } else {
        uchar t0[16], t1[16], tu[8], tv[8];
        *(uchar16 *)t0 = __builtin_convertvector(o0, uchar16);
        *(uchar16 *)t1 = __builtin_convertvector(o1, uchar16);
        *(uchar8 *)tu = __builtin_convertvector(un, uchar8);
        *(uchar8 *)tv = __builtin_convertvector(vn, uchar8);
        for (int i = 0; i < 8; ++i) {
            if (!(i < LANES && ci + i >= cx0 && ci + i < cx1))
                continue;
            yp[lo + 2 * i] = t0[2 * i];
            yp[lo + 2 * i + 1] = t0[2 * i + 1];
#if CY == 2
            yp[lo + y_stride + 2 * i] = t1[2 * i];
            yp[lo + y_stride + 2 * i + 1] = t1[2 * i + 1];
#endif
            up[co + i] = tu[i];
            vp[co + i] = tv[i];
        }
    }
}
