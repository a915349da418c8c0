/* Relighting: reflectance maps x environment (relight.kernels.relighter; NumPy twins there).
 *
 * relight_compact: out[p, c] = sum_j V[p, c, j] coef[j, c]        (the rank-k part)
 *                            + sum_s rows[t_s, c, p] light_s[c]   (the brightest texels, exact)
 *                  32 pixels a work item; with rank 0 it is the single-light path (render --light).
 * relight_exact:   out[p, c] = sum_t maps[p, c, t] lp[c, t]       (every 32-texel block with light)
 *
 * Data are half floats read as pairs packed in 32-bit words and widened with integer ops;
 * every sum accumulates in float.
 * Why: PoCL 3.0 compiles vload_half16 (and vload16) into an out-of-line call around which every vector register is spilled to the stack - measured 12
 * GB/s for a plain read of half data, against 16 GB/s with this decode and 21 GB/s for float
 * data on the development machine. The pairs split into even and odd lanes: pixels (2i, 2i+1)
 * in the compact layout, texels (2i, 2i+1) in the exact one; the host lays out the light the same way.
 *
 * Each work item writes its pixels' RGB into the frame at frame_index[p] (the rest of the frame
 * is left as it is).
 */

/* 64-byte loads at any 2-byte alignment (clang lowers a dereference through this type to an
   unaligned vector load, inline). */
typedef uint16 uint16_u __attribute__((aligned(2)));

/* The low / high half of each word as float: the sign and magnitude bits moved into a float's
   place, then scaled by 2^112 to rebias the exponent. Exact for every normal half; subnormal
   halves would become float subnormals, which cost a ~100-cycle microcode assist per vector:
   the program is built with denormals flushed, so they read as zero (bundles store none, see
   relight.numerics.HALF_TINY; measured 2.2x faster on real maps than with the assists). */
inline float16 half_lo(uint16 w)
{
    return as_float16(((w & 0x8000u) << 16) | ((w & 0x7fffu) << 13)) * 0x1p112f;
}

inline float16 half_hi(uint16 w)
{
    return as_float16((w & 0x80000000u) | ((w >> 3) & 0x0fffe000u)) * 0x1p112f;
}

typedef union { float16 v; float s[16]; } f16_lanes;

/* 32 halves starting at x[0], or fewer (zeros after n): the last, partial pixel block. */
inline uint16 load_tail(__global const ushort *x, int n)
{
    union { uint16 v; uint s[16]; } w;
    for (int i = 0; i < 16; ++i) {
        uint lo = 2 * i < n ? x[2 * i] : 0u;
        uint hi = 2 * i + 1 < n ? x[2 * i + 1] : 0u;
        w.s[i] = lo | (hi << 16);
    }
    return w.v;
}

__kernel void relight_compact(
    __global const uint16 *v, int rank, int kp,          /* (P / 32, kp, 3, 32) halves: the first `rank` used */
    __constant float4 *coef,                             /* (rank,) rgb coefficients */
    __global const ushort *rows, int plane,              /* (T, 3, plane) halves: texel-major maps */
    __constant float4 *direct, int n_direct,             /* (n,) rgb light of texel (int)w */
    __global const int *frame_index, int n_pix,          /* (P,) pixel -> index in the frame */
    __global float *frame)                               /* (H * W * 3) */
{
    int g = get_global_id(0);
    int p0 = g * 32;
    if (p0 >= n_pix)
        return;
    __global const uint16 *blk = v + (size_t)g * 3 * kp;
    float16 re = 0.0f, ro = 0.0f, ge = 0.0f, go = 0.0f, be = 0.0f, bo = 0.0f;
    for (int j = 0; j < rank; ++j) {
        float4 c = coef[j];
        uint16 w = blk[3 * j];
        re += half_lo(w) * c.x;
        ro += half_hi(w) * c.x;
        w = blk[3 * j + 1];
        ge += half_lo(w) * c.y;
        go += half_hi(w) * c.y;
        w = blk[3 * j + 2];
        be += half_lo(w) * c.z;
        bo += half_hi(w) * c.z;
    }
    int n_here = min(32, plane - p0);
    for (int s = 0; s < n_direct; ++s) {
        float4 l = direct[s];
        __global const ushort *row = rows + (size_t)(int)l.w * 3 * plane + p0;
        uint16 wr, wg, wb;
        if (n_here == 32) {
            wr = *(__global const uint16_u *)row;
            wg = *(__global const uint16_u *)(row + plane);
            wb = *(__global const uint16_u *)(row + 2 * (size_t)plane);
        } else {
            wr = load_tail(row, n_here);
            wg = load_tail(row + plane, n_here);
            wb = load_tail(row + 2 * (size_t)plane, n_here);
        }
        re += half_lo(wr) * l.x;
        ro += half_hi(wr) * l.x;
        ge += half_lo(wg) * l.y;
        go += half_hi(wg) * l.y;
        be += half_lo(wb) * l.z;
        bo += half_hi(wb) * l.z;
    }
    f16_lanes r_e = {re}, r_o = {ro}, g_e = {ge}, g_o = {go}, b_e = {be}, b_o = {bo};
    int n = min(32, n_pix - p0);
    for (int i = 0; i < 16; ++i) {
        if (2 * i < n) {
            size_t o = (size_t)frame_index[p0 + 2 * i] * 3;
            frame[o] = r_e.s[i];
            frame[o + 1] = g_e.s[i];
            frame[o + 2] = b_e.s[i];
        }
        if (2 * i + 1 < n) {
            size_t o = (size_t)frame_index[p0 + 2 * i + 1] * 3;
            frame[o] = r_o.s[i];
            frame[o + 1] = g_o.s[i];
            frame[o + 2] = b_o.s[i];
        }
    }
}

inline float hsum16(float16 a)
{
    float8 b = a.lo + a.hi;
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
        re += half_lo(w) * lp[2 * i];
        ro += half_hi(w) * lp[2 * i + 1];
        w = mine[nb + i];
        ge += half_lo(w) * lp[2 * (nb + i)];
        go += half_hi(w) * lp[2 * (nb + i) + 1];
        w = mine[2 * nb + i];
        be += half_lo(w) * lp[2 * (2 * nb + i)];
        bo += half_hi(w) * lp[2 * (2 * nb + i) + 1];
    }
    size_t o = (size_t)frame_index[p] * 3;
    frame[o] = hsum16(re + ro);
    frame[o + 1] = hsum16(ge + go);
    frame[o + 2] = hsum16(be + bo);
}

/* The decode alone, for tests: packed pairs -> (low, high) floats. */
__kernel void decode_half_pairs(__global const uint16 *w, __global float16 *lo, __global float16 *hi)
{
    int g = get_global_id(0);
    lo[g] = half_lo(w[g]);
    hi[g] = half_hi(w[g]);
}
