/* Reflectance maps from light samples (relight.kernels.maps; NumPy twin:
 * relight.kernels.reflectance.visibility_maps / build_maps).
 *
 * Every per-pixel array is planar with the pixels innermost - (rows, n_pix) - so neighbouring
 * pixels are neighbouring lanes: soft_visibility and box3 are one (pixel, texel) per work-item
 * (PoCL vectorises their work-groups), build_maps and visibility_at 16 pixels per work-item as
 * explicit vectors (PoCL's own vectoriser gives up on their bodies).
 *
 * soft_visibility: per (pixel, texel), whether the texel's direction clears the pixel's horizon
 *   (soft over VIS_SOFT of elevation), from a horizon table over image-plane directions.
 * box3: the paper's 3x3 box filter of those maps (wrapping in azimuth, clamped at the poles).
 * visibility_at: the two above at a few texels only (the triangulation's vertices).
 * build_maps: per pixel and active texel, the value interpolated from its triangle's vertices with
 *   visibility-aware blending and light adaptation (paper Eq. 1-3); written texel-major
 *   (T_pad, 3, n) float32.
 * pixel_major_f32 / _f16: that layout transposed to the pixel-major rows relighting reads.
 *
 * Build options (constants, so their branches fold away): ADAPT (light adaptation), USE_VIS
 * (visibility), USE_TREND (the shading model added back), USE_SPLINE (the thin-plate spline
 * blended in), each 0/1; SPEC_EXP (the specular lobe's whole exponent); SPLINE_ROOT25 (the
 * spline values come in its power domain of exponent 0.4: clipped at 0 and raised to 2.5 here).
 */
#include "common.h"

#define MIN_COS 0.1f
#ifndef SPEC_EXP
#define SPEC_EXP 8
#endif
#ifndef ADAPT
#define ADAPT 1
#endif
#ifndef USE_VIS
#define USE_VIS 1
#endif
#ifndef USE_TREND
#define USE_TREND 1
#endif
#ifndef USE_SPLINE
#define USE_SPLINE 0
#endif
#ifndef SPLINE_ROOT25
#define SPLINE_ROOT25 0
#endif
__kernel void soft_visibility(
    __global const float *restrict horizon, int n_pix_all, /* (n_az, P_all) horizon elevations (radians) */
    __global const float *restrict texel_az, int n_tex, /* (T, 4) azimuth columns x, y; blend; elevation */
    float inv_soft, int p0, int n_pix,                /* pixel range [p0, p0 + n_pix) */
    __global float *restrict out, int stride)         /* (T, stride >= n_pix): texel-major */
{
    int i = get_global_id(0); /* pixels fastest: contiguous reads and writes */
    int t = get_global_id(1);
    if (i >= n_pix || t >= n_tex)
        return;
    int c0 = (int)texel_az[4 * t], c1 = (int)texel_az[4 * t + 1];
    float blend = texel_az[4 * t + 2], elev = texel_az[4 * t + 3];
    float h0 = horizon[(size_t)c0 * n_pix_all + p0 + i];
    float h1 = horizon[(size_t)c1 * n_pix_all + p0 + i];
    /* elevation >= 4 marks "straight at the camera": always visible */
    out[(size_t)t * stride + i] = elev < 4.0f ? clamp01(0.5f + (elev - lerpf(h0, h1, blend)) * inv_soft) : 1.0f;
}

__kernel void box3(__global const float *restrict in, int w, int h, int n_pix, __global float *restrict out)
{
    int i = get_global_id(0); /* pixels fastest; maps texel-major (T, n_pix) */
    int x = get_global_id(1);
    int y = get_global_id(2);
    if (i >= n_pix || x >= w || y >= h)
        return;
    int xl = x == 0 ? w - 1 : x - 1, xr = x == w - 1 ? 0 : x + 1;
    int ya = y == 0 ? 0 : y - 1, yb = y == h - 1 ? h - 1 : y + 1;
    float acc = 0.0f;
    __global const float *r0 = in + (size_t)(ya * w) * n_pix + i;
    __global const float *r1 = in + (size_t)(y * w) * n_pix + i;
    __global const float *r2 = in + (size_t)(yb * w) * n_pix + i;
    acc += r0[(size_t)xl * n_pix] + r0[(size_t)x * n_pix] + r0[(size_t)xr * n_pix];
    acc += r1[(size_t)xl * n_pix] + r1[(size_t)x * n_pix] + r1[(size_t)xr * n_pix];
    acc += r2[(size_t)xl * n_pix] + r2[(size_t)x * n_pix] + r2[(size_t)xr * n_pix];
    out[(size_t)(y * w + x) * n_pix + i] = acc * (1.0f / 9.0f);
}

/* build_maps and visibility_at work on LANES pixels per work-item as explicit vectors (PoCL's own
 * vectoriser of a work-group's items gives up on such bodies: its SLP pass pairs lines first). */
#define LANES 16
typedef float16 vf;
/* No vf is passed to or returned from a function - helpers are macros or take pointers, and no
 * library builtin (sqrt, vstore16, ...) is called on one: PoCL 3.0 compiles a kernel for the CPU
 * LLVM 14 names (AMD's Zen 4 is "znver3", without AVX-512) but links the builtins of the kernel
 * library its features select (avx512), so a 64-byte vector crossing a call changes the ABI on
 * the way (clang warns) or fails to compile (LLVM's "Cannot select" in _cl_sqrt(float16)). */
#define VMX(a, b) ((a) > (b) ? (a) : (b))
#define VMN(a, b) ((a) < (b) ? (a) : (b))
#define VCLAMP01(x) VMN(VMX((x), (vf)(0.0f)), (vf)(1.0f))
/* sqrt lane by lane: __builtin_sqrtf is LLVM's sqrt intrinsic (the instruction, correctly
 * rounded), where sqrt() would be a library call */
#define VSQRT(x)                                                                                   \
    ((vf)(__builtin_sqrtf((x).s0), __builtin_sqrtf((x).s1), __builtin_sqrtf((x).s2),              \
          __builtin_sqrtf((x).s3), __builtin_sqrtf((x).s4), __builtin_sqrtf((x).s5),              \
          __builtin_sqrtf((x).s6), __builtin_sqrtf((x).s7), __builtin_sqrtf((x).s8),              \
          __builtin_sqrtf((x).s9), __builtin_sqrtf((x).sa), __builtin_sqrtf((x).sb),              \
          __builtin_sqrtf((x).sc), __builtin_sqrtf((x).sd), __builtin_sqrtf((x).se),              \
          __builtin_sqrtf((x).sf)))
#define LOADV(ptr) (*(__global const vf *)(ptr))

/* Light-adapted interpolation (paper Eq. 1-3) with vertex weights w (times a use share), as the
 * three coefficients k of the vertex values: the result is k0 c0 + k1 c1 + k2 c2 in every channel.
 * The included unlit vertices give the indirect light c_ind; the lit ones their light less it,
 * cosine-adapted, and c_ind is added back (no lit vertex: the plain interpolation; all lit: the
 * cosine adaptation alone - special cases of this one form, so no branch). d: n . vertex. */
inline void adapt_k(const vf *w, const vf *d, const vf *dps, vf *k)
{
    vf inv = 1.0f / VMX(w[0] + w[1] + w[2], (vf)(1e-12f));
    vf w0 = w[0] * inv, w1 = w[1] * inv, w2 = w[2] * inv;
#if ADAPT
    vf zero = (vf)(0.0f), mc = (vf)(MIN_COS);
    vf l0 = d[0] > mc ? w0 : zero, l1 = d[1] > mc ? w1 : zero, l2 = d[2] > mc ? w2 : zero;
    vf i0 = w0 - l0, i1 = w1 - l1, i2 = w2 - l2;
    vf w_lit = l0 + l1 + l2;
    vf a0 = l0 / VMX(d[0], mc), a1 = l1 / VMX(d[1], mc), a2 = l2 / VMX(d[2], mc);
    vf scale = *dps * w_lit / VMX(w_lit, (vf)(1e-12f));
    vf b = w_lit + 1.0f - scale * (a0 + a1 + a2);
    k[0] = scale * a0 + b * i0;
    k[1] = scale * a1 + b * i1;
    k[2] = scale * a2 + b * i2;
#else
    k[0] = w0;
    k[1] = w1;
    k[2] = w2;
#endif
}

__kernel void build_maps(
    __global const float *restrict vals,               /* (K + 1, 3, n_pix) vertex values, the last row 0 */
    __global const float *restrict normal,             /* (3, n_pix) */
    __global const int *restrict tex_int,              /* (A, 8) rows of vals of its triangle (black lights:
                                                          K), its spline row (-1: none), its vertices'
                                                          texels, its own texel */
    __global const float *restrict tex_f,              /* (A, 20) barycentric weights, 0, its vertices'
                                                          directions (3 x 3), its direction, its half
                                                          vector with +Z (0: none), 0 */
    __global const float *restrict vis,                /* (T, n_pix) smoothed visibility (USE_VIS) */
    /* trend: out = interpolation - offset + (coef * max(n . l, 0) + spec * lobe(l)) * visibility
       (the shading model; lobe = max(n . h, 0)^SPEC_EXP where n . l > 0, h the half vector of l and +Z) */
    __global const float *restrict trend,              /* (9, n_pix): offset, coef, spec (USE_TREND) */
    /* spline (USE_SPLINE): out = w * out + (1 - w) * min(spline, the brightest of the triangle's
       three samples) at texels inside the samples' hull, w the pixel's weight */
    __global const float *restrict spline,             /* (Q, 3, n_pix) spline values */
    __global const float *restrict raw,                /* (K + 1, 3, n_pix) the samples themselves */
    __global const float *restrict weight,             /* (n_pix,) */
    int n_pix, __global float *restrict out)           /* (T_pad, 3, n_pix) */
{
    /* The range is (n_pix / LANES, n_active): the host pads the pixels to whole vectors and
       aligns every row to 64 bytes. */
    int i = get_global_id(0) * LANES;
    int a = get_global_id(1);
    vf zero = (vf)(0.0f);
    vf nx = LOADV(normal + i), ny = LOADV(normal + n_pix + i), nz = LOADV(normal + 2 * n_pix + i);
    __global const int *ti = tex_int + 8 * a;
    __global const float *tf = tex_f + 20 * a;
    vf tw[3] = {(vf)(tf[0]), (vf)(tf[1]), (vf)(tf[2])};
    vf d[3] = {(vf)(1.0f), (vf)(1.0f), (vf)(1.0f)};
#if ADAPT
    d[0] = nx * tf[4] + ny * tf[5] + nz * tf[6];
    d[1] = nx * tf[7] + ny * tf[8] + nz * tf[9];
    d[2] = nx * tf[10] + ny * tf[11] + nz * tf[12];
#endif
    vf nl = nx * tf[13] + ny * tf[14] + nz * tf[15];
    vf dps = ADAPT ? VMX(nl, zero) : (vf)(1.0f);
    vf k[3];
    adapt_k(tw, d, &dps, k);
    vf vp = (vf)(1.0f);
#if USE_VIS
    {
        vf v0 = LOADV(vis + (size_t)ti[4] * n_pix + i), v1 = LOADV(vis + (size_t)ti[5] * n_pix + i);
        vf v2 = LOADV(vis + (size_t)ti[6] * n_pix + i);
        vp = LOADV(vis + (size_t)ti[7] * n_pix + i);
        vf vmin = VMN(v0, VMN(v1, v2));
        vf spread = VMX(v0, VMX(v1, v2)) - vmin;
        /* The least visible vertex is shadowed, the most lit, the third by its share; the texel's
           own visibility chooses between the two interpolations (no spread: unchanged). */
        vf inv = 1.0f / VMX(spread, (vf)(1e-6f));
        vf s0 = VCLAMP01((v0 - vmin) * inv), s1 = VCLAMP01((v1 - vmin) * inv), s2 = VCLAMP01((v2 - vmin) * inv);
        vf tl = VCLAMP01((vp - vmin) * inv);
        vf wl[3] = {tw[0] * s0, tw[1] * s1, tw[2] * s2};
        vf ws[3] = {tw[0] * (1.0f - s0), tw[1] * (1.0f - s1), tw[2] * (1.0f - s2)};
        vf c[3], e[3];
        adapt_k(wl, d, &dps, c);
        adapt_k(ws, d, &dps, e);
        vf keep = 1.0f - spread, lit = spread * tl, shade = spread * (1.0f - tl);
        for (int j = 0; j < 3; ++j)
            k[j] = keep * k[j] + lit * c[j] + shade * e[j];
    }
#endif
    vf tr_c = zero, tr_s = zero;
#if USE_TREND
    {
        vf nh = VMX(nx * tf[16] + ny * tf[17] + nz * tf[18], zero);
        /* nh ** SPEC_EXP by squaring (as ipow), unrolled: SPEC_EXP < 256 */
        vf r = (vf)(1.0f), x = nh;
#define SQ_STEP(bit) if ((SPEC_EXP >> (bit)) & 1) r *= x; x *= x;
        SQ_STEP(0) SQ_STEP(1) SQ_STEP(2) SQ_STEP(3) SQ_STEP(4) SQ_STEP(5) SQ_STEP(6) SQ_STEP(7)
#undef SQ_STEP
        tr_c = VMX(nl, zero) * vp;
        tr_s = (nl > zero ? r : zero) * vp;
    }
#endif
    size_t s3 = (size_t)3 * n_pix;
    __global const float *p0 = vals + ti[0] * s3 + i, *p1 = vals + ti[1] * s3 + i, *p2 = vals + ti[2] * s3 + i;
    __global float *o = out + (size_t)a * s3 + i;
    for (int c = 0; c < 3; ++c) {
        size_t off = (size_t)c * n_pix;
        vf res = k[0] * LOADV(p0 + off) + k[1] * LOADV(p1 + off) + k[2] * LOADV(p2 + off);
#if USE_TREND
        res += LOADV(trend + 3 * n_pix + off + i) * tr_c + LOADV(trend + 6 * n_pix + off + i) * tr_s
               - LOADV(trend + off + i);
#endif
        res = VMX(res, zero);
#if USE_SPLINE
        if (ti[3] >= 0) {
            vf cap = VMX(LOADV(raw + ti[0] * s3 + off + i), VMX(LOADV(raw + ti[1] * s3 + off + i),
                                                                 LOADV(raw + ti[2] * s3 + off + i)));
            vf sv = LOADV(spline + ti[3] * s3 + off + i);
#if SPLINE_ROOT25
            sv = VMX(sv, zero);
            sv = sv * sv * VSQRT(sv);
#endif
            vf sp = VMN(sv, cap);
            vf w = LOADV(weight + i);
            res = VMX(w * res + (1.0f - w) * sp, zero);
        }
#endif
        *(__global vf *)(o + off) = res;
    }
}

/* The maps of a chunk texel-major (A, 3, n_pix) -> pixel-major rows (P, 3, t_pad) from pixel
 * p0 on, 16 texels per work-item (the padding texels past A written as 0), float32 or halves
 * (round to nearest even). Range: (n_valid, t_pad / 16, 3). Stores through unaligned vector
 * types and the half conversion in integer ops: no library call on a 16-wide vector (above). */
typedef float16 float16_u __attribute__((aligned(4)));
typedef ushort16 ushort16_u __attribute__((aligned(2)));
#define PM_GATHER                                                                               \
    int i = get_global_id(0), b = get_global_id(1) * 16, c = get_global_id(2);                  \
    float v[16];                                                                                \
    for (int j = 0; j < 16; ++j)                                                                \
        v[j] = b + j < n_active ? in[((size_t)(b + j) * 3 + c) * n_pix + i] : 0.0f;             \
    float16 x = (float16)(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8], v[9], v[10],    \
                          v[11], v[12], v[13], v[14], v[15]);                                   \
    size_t o = ((size_t)(p0 + i) * 3 + c) * t_pad + b;

__kernel void pixel_major_f32(__global const float *restrict in, int n_active, int n_pix, int p0, int t_pad,
                              __global float *restrict out)
{
    PM_GATHER
    *(__global float16_u *)(out + o) = x;
}

/* float -> IEEE half bits, rounded to nearest even as vstore_half_rte: overflow to infinity,
 * NaN kept (quiet), halves below the normal range made by a float addition that rounds them
 * (0.5f's exponent puts the half's last subnormal bit at the float's last mantissa bit), the
 * normal range by rebiasing the exponent and rounding the 13 dropped bits. */
#define HALF_BITS_RTE(x, out)                                                                   \
    {                                                                                           \
        uint16 f_ = as_uint16(x);                                                               \
        uint16 s_ = f_ & 0x80000000u;                                                           \
        f_ ^= s_;                                                                               \
        uint16 inf_ = f_ > 0x7f800000u ? (uint16)(0x7e00u) : (uint16)(0x7c00u);                 \
        uint16 sub_ = as_uint16(as_float16(f_) + 0.5f) - 0x3f000000u;                           \
        uint16 nrm_ = (f_ + 0xc8000fffu + ((f_ >> 13) & 1u)) >> 13;                             \
        uint16 h_ = f_ >= 0x47800000u ? inf_ : (f_ < 0x38800000u ? sub_ : nrm_);                \
        out = __builtin_convertvector(h_ | (s_ >> 16), ushort16);                               \
    }

__kernel void pixel_major_f16(__global const float *restrict in, int n_active, int n_pix, int p0, int t_pad,
                              __global half *restrict out)
{
    PM_GATHER
    ushort16 h;
    HALF_BITS_RTE(x, h)
    *(__global ushort16_u *)((__global ushort *)out + o) = h;
}

/* The smoothed visibility (soft_visibility then box3) at a few texels only - the triangulation's
 * vertices - for LANES pixels per work-item: the mean of the soft visibility over each texel's
 * 3x3 neighbourhood. Range (n_pix / LANES, n_cols); out (n_cols, n_pix). */
__kernel void visibility_at(
    __global const float *restrict horizon, int n_pix_all, int p0,  /* (n_az, >= P_all) padded to LANES */
    __global const float *restrict texel_az,                       /* (T, 4) as soft_visibility */
    __global const int *restrict nb,                               /* (n_cols, 9) neighbourhood texels */
    float inv_soft, int n_pix, __global float *restrict out)
{
    int i = get_global_id(0) * LANES;
    int col = get_global_id(1);
    vf acc = (vf)(0.0f);
    for (int j = 0; j < 9; ++j) {
        int t = nb[9 * col + j];
        float elev = texel_az[4 * t + 3];
        if (elev < 4.0f) { /* (uniform over the lanes) elevation >= 4: straight at the camera */
            vf h0 = LOADV(horizon + (size_t)(int)texel_az[4 * t] * n_pix_all + p0 + i);
            vf h1 = LOADV(horizon + (size_t)(int)texel_az[4 * t + 1] * n_pix_all + p0 + i);
            acc += VCLAMP01(0.5f + (elev - (h0 + (h1 - h0) * texel_az[4 * t + 2])) * inv_soft);
        } else {
            acc += 1.0f;
        }
    }
    *(__global vf *)(out + (size_t)col * n_pix + i) = acc * (1.0f / 9.0f);
}
