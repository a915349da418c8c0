/* Relighting: reflectance maps x environment (relight.kernels.relighter; NumPy twins there).
 *
 * relight_compact: out[p, c] = peak8[p, c] sum_j<k8 q8[p, c, j] coef[j, c]     (the first ranks, 8-bit)
 *                            + peak4[p, c] sum_j<k4 q4[p, c, j] coef[k8 + j, c] (the rest, 4-bit)
 *                            + sum_s rows[t_s, c, p] light_s[c]                  (the brightest texels, exact)
 *                  32 pixels a work item; with rank 0 it is the single-light path (render --light).
 * relight_exact:   out[p, c] = sum_t maps[p, c, t] lp[c, t]       (every 32-texel block with light)
 *
 * The compact basis is read as the bundle stores it - signed bytes for the first ranks, signed
 * 4-bit steps for the rest, each with a peak (a half) per pixel and channel (the host divides
 * the coefficients by the levels, 127 and 7) - so a call streams 3 k8 + 1.5 k4 + 12 + 6n bytes
 * per pixel (n exact texels) instead of 6k + 6n as halves: the kernel
 * is bound by memory reads. Steps are widened with __builtin_convertvector (clang's inline sign
 * extension and conversion: vpmovsxbd + vcvtdq2ps, no library call); nibbles by two shifts.
 *
 * Half floats are read as words and widened with integer ops; every sum accumulates in float.
 * Why: PoCL 3.0 compiles vload_half16 (and vload16) into an out-of-line call around which every
 * vector register is spilled to the stack - measured 12 GB/s for a plain read of half data,
 * against 16 GB/s with this decode and 21 GB/s for float data on the development machine. The
 * exact path's pairs split into even and odd lanes (texels 2i, 2i+1); the host lays out the
 * light the same way. The compact path's direct rows widen 16 halves at a time, in pixel order.
 *
 * Each work item writes its pixels' RGB into the frame at frame_index[p] (the rest of the frame
 * is left as it is).
 */

/* 64-byte loads at any 2-byte alignment (clang lowers a dereference through this type to an
   unaligned vector load, inline). */
typedef ushort16 ushort16_u __attribute__((aligned(2)));

/* The low / high half of each word as float: the sign and magnitude bits moved into a float's
   place, then scaled by 2^112 to rebias the exponent. Exact for every normal half; subnormal
   halves would become float subnormals, which cost a ~100-cycle microcode assist per vector:
   the program is built with denormals flushed, so they read as zero (bundles store none, see
   relight.numerics.HALF_TINY; measured 2.2x faster on real maps than with the assists).
   Macros, not functions: a 64-byte vector passed to or returned from a function changes the
   ABI where PoCL compiles for a CPU name without AVX-512 (see reflectance.cl). */
#define HALF_LO(w) (as_float16((((w) & 0x8000u) << 16) | (((w) & 0x7fffu) << 13)) * 0x1p112f)
#define HALF_HI(w) (as_float16(((w) & 0x80000000u) | (((w) >> 3) & 0x0fffe000u)) * 0x1p112f)

/* 16 halves (as ushort) -> float: the half's sign and magnitude bits moved into a float's
   place and rescaled (see HALF_LO); the natural pixel order. */
#define HALVES16(h) HALF_LO(__builtin_convertvector((h), uint16))

/* 32 halves of one direct row from x[0] (fewer at the face's last block: zeros after n). */
inline void load_row(__global const ushort *x, int n, float16 *lo, float16 *hi)
{
    if (n == 32) {
        *lo = HALVES16(*(__global const ushort16_u *)x);
        *hi = HALVES16(*(__global const ushort16_u *)(x + 16));
        return;
    }
    union { ushort16 v[2]; ushort s[32]; } w;
    for (int i = 0; i < 32; ++i)
        w.s[i] = i < n ? x[i] : (ushort)0;
    *lo = HALVES16(w.v[0]);
    *hi = HALVES16(w.v[1]);
}

__kernel void relight_compact(
    __global const char16 *q8, int rank8, int kp8,       /* (P / 32, kp8, 3, 32) int8: the first ranks */
    __global const ushort16 *unit8,                     /* (P / 32, 3, 32) halves: their peak (step x 127) per pixel, channel */
    __global const char16 *q4, int rank4, int kp4,       /* (P / 32, kp4, 3, 16) two 4-bit steps a byte: the rest */
    __global const ushort16 *unit4,                     /* (P / 32, 3, 32) halves: their peak (step x 7) */
    __constant float4 *coef,                             /* (rank8 + rank4,) rgb coefficients / 127 or / 7 */
    __global const ushort *rows, int plane,              /* (T, 3, plane) halves: texel-major maps */
    __constant float4 *direct, int n_direct,             /* (n,) rgb light of texel (int)w */
    __global const int *frame_index, int n_pix,          /* (P,) pixel -> index in the frame */
    __global float *frame)                               /* (H * W * 3) */
{
    int g = get_global_id(0);
    int p0 = g * 32;
    if (p0 >= n_pix)
        return;
    /* The rank-k part in steps of the storage: each pixel's step multiplies its sum once. */
    float16 r0 = 0.0f, r1 = 0.0f, g0 = 0.0f, g1 = 0.0f, b0 = 0.0f, b1 = 0.0f;
    __global const char16 *blk = q8 + (size_t)g * 6 * kp8;
    for (int j = 0; j < rank8; ++j) {
        float4 c = coef[j];
        __global const char16 *x = blk + 6 * j;
        r0 += __builtin_convertvector(x[0], float16) * c.x;
        r1 += __builtin_convertvector(x[1], float16) * c.x;
        g0 += __builtin_convertvector(x[2], float16) * c.y;
        g1 += __builtin_convertvector(x[3], float16) * c.y;
        b0 += __builtin_convertvector(x[4], float16) * c.z;
        b1 += __builtin_convertvector(x[5], float16) * c.z;
    }
    __global const ushort16 *u = unit8 + (size_t)g * 6;
    r0 *= HALVES16(u[0]);
    r1 *= HALVES16(u[1]);
    g0 *= HALVES16(u[2]);
    g1 *= HALVES16(u[3]);
    b0 *= HALVES16(u[4]);
    b1 *= HALVES16(u[5]);
    if (rank4 > 0) {
        /* byte i: pixel i in the low four bits, pixel i + 16 in the high four (both signed) */
        float16 s0 = 0.0f, s1 = 0.0f, t0 = 0.0f, t1 = 0.0f, v0 = 0.0f, v1 = 0.0f;
        __global const char16 *nb = q4 + (size_t)g * 3 * kp4;
        for (int j = 0; j < rank4; ++j) {
            float4 c = coef[rank8 + j];
            __global const char16 *x = nb + 3 * j;
            int16 w = __builtin_convertvector(x[0], int16);
            s0 += __builtin_convertvector((w << 28) >> 28, float16) * c.x;
            s1 += __builtin_convertvector(w >> 4, float16) * c.x;
            w = __builtin_convertvector(x[1], int16);
            t0 += __builtin_convertvector((w << 28) >> 28, float16) * c.y;
            t1 += __builtin_convertvector(w >> 4, float16) * c.y;
            w = __builtin_convertvector(x[2], int16);
            v0 += __builtin_convertvector((w << 28) >> 28, float16) * c.z;
            v1 += __builtin_convertvector(w >> 4, float16) * c.z;
        }
        u = unit4 + (size_t)g * 6;
        r0 += s0 * HALVES16(u[0]);
        r1 += s1 * HALVES16(u[1]);
        g0 += t0 * HALVES16(u[2]);
        g1 += t1 * HALVES16(u[3]);
        b0 += v0 * HALVES16(u[4]);
        b1 += v1 * HALVES16(u[5]);
    }
    int n_here = min(32, plane - p0);
    for (int s = 0; s < n_direct; ++s) {
        float4 l = direct[s];
        __global const ushort *row = rows + (size_t)(int)l.w * 3 * plane + p0;
        float16 lo, hi;
        load_row(row, n_here, &lo, &hi);
        r0 += lo * l.x;
        r1 += hi * l.x;
        load_row(row + plane, n_here, &lo, &hi);
        g0 += lo * l.y;
        g1 += hi * l.y;
        load_row(row + 2 * (size_t)plane, n_here, &lo, &hi);
        b0 += lo * l.z;
        b1 += hi * l.z;
    }
    union { float16 v[2]; float s[32]; } R = {{r0, r1}}, G = {{g0, g1}}, B = {{b0, b1}};
    int n = min(32, n_pix - p0);
    for (int i = 0; i < n; ++i) {
        size_t o = (size_t)frame_index[p0 + i] * 3;
        frame[o] = R.s[i];
        frame[o + 1] = G.s[i];
        frame[o + 2] = B.s[i];
    }
}

/* The sum of 16 lanes (by pointer: see HALF_LO). */
inline float hsum16(const float16 *a)
{
    float8 b = a->lo + a->hi;
    float4 c = b.lo + b.hi;
    return c.x + c.y + c.z + c.w;
}

__kernel void relight_exact(
    __global const uint16 *maps, int tp, int n_pix,      /* (P, 3, tp) halves, tp a multiple of 32 */
    __global const float16 *lp,                          /* (3, tp / 32, 2): even, odd texels of each block */
    __global const int *blocks, int n_blocks,            /* the 32-texel blocks that have light */
    __global const int *frame_index,
    __global float *frame)
{
    int p = get_global_id(0);
    if (p >= n_pix)
        return;
    int nb = tp / 32;
    __global const uint16 *mine = maps + (size_t)p * 3 * nb;
    float16 re = 0.0f, ro = 0.0f, ge = 0.0f, go = 0.0f, be = 0.0f, bo = 0.0f;
    for (int j = 0; j < n_blocks; ++j) {
        int i = blocks[j];
        uint16 w = mine[i];
        re += HALF_LO(w) * lp[2 * i];
        ro += HALF_HI(w) * lp[2 * i + 1];
        w = mine[nb + i];
        ge += HALF_LO(w) * lp[2 * (nb + i)];
        go += HALF_HI(w) * lp[2 * (nb + i) + 1];
        w = mine[2 * nb + i];
        be += HALF_LO(w) * lp[2 * (2 * nb + i)];
        bo += HALF_HI(w) * lp[2 * (2 * nb + i) + 1];
    }
    size_t o = (size_t)frame_index[p] * 3;
    float16 r = re + ro, gg = ge + go, bb = be + bo;
    frame[o] = hsum16(&r);
    frame[o + 1] = hsum16(&gg);
    frame[o + 2] = hsum16(&bb);
}

/* The decode alone, for tests: packed pairs -> (low, high) floats. */
__kernel void decode_half_pairs(__global const uint16 *w, __global float16 *lo, __global float16 *hi)
{
    int g = get_global_id(0);
    lo[g] = HALF_LO(w[g]);
    hi[g] = HALF_HI(w[g]);
}
