/* The relit face warped into a video frame and composited, in two passes.
 *
 * build_layer (reference crop, one work item per crop pixel): a float4 layer
 *     transfer: (gain (relit + eps) / (ambient + eps) clamped to [0, ratio_max], alpha)
 *     paste:    (gain relit, alpha)
 *   with relit read through `fill` (crop pixel -> relit frame pixel, -1 = none: the nearest
 *   face pixel fills the feathered fringe) and alpha = feathered mask x strength.
 * warp_composite (the face's box in the frame, sRGB uint8 RGB, modified in place):
 *   1. the pixel's reference position: bilinear in a coarse inverse map (gh, gw) of float2
 *      reference pixels sampled every `step` frame pixels (one extra grid point on each side of
 *      the box; x < OUTSIDE_HALF marks grid points outside the warp) - inside only when all
 *      four grid points around it are;
 *   2. one bilinear float4 sample of the layer there (zero outside the crop);
 *   3. transfer: out = frame (1 + a (r - 1)); paste: out = frame + a (r - frame);
 *   4. sRGB encode through the 16k-entry table (as relight.colour.encode_srgb8).
 * Pixels outside the warp keep their bytes. (One float4 layer instead of three bilinear samples
 * with an indirection per pixel: measured 8 ms -> see relight.kernels.compositor.)
 */

#define OUTSIDE_HALF (-5.0e3f)
/* Camera-facing component of a turned normal below which the face fades out, and above which
   it is fully composited (relight.kernels.compositor.FACING). */
#define FACING_LO 0.15f
#define FACING_HI 0.45f

/* PoCL 3.0 calls its math builtins (floor, clamp, ...) out of line, spilling vector registers
   around each call (measured: this kernel took 9 ms for a 300x450 box with them): these
   inline stand-ins are exact for the ranges used here. */
__attribute__((always_inline)) inline int ifloor(float x)
{
    int t = (int)x;                 /* truncation toward zero */
    return t - (((float)t > x) ? 1 : 0);
}

__attribute__((always_inline)) inline float fclamp(float v, float lo, float hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

__attribute__((always_inline)) inline uchar encode(__global const uchar *lut, int n, float v)
{
    float i = fclamp(v * (float)n + 0.5f, 0.0f, (float)n);
    return lut[(int)i];
}

/* One pixel of the box (see the file comment). */
__kernel void build_layer(
    __global const float *relit, __global const int *fill,   /* relit frame (.., 3); (ch * cw,) indices */
    __global const float *inv_amb, __global const float *alpha,
    __global const float *normal, float rz0, float rz1, float rz2, /* (ch * cw, 3); the head rotation's z row */
    __global const int *support, int n,                      /* the crop pixels with alpha > 0 */
    int transfer, float gain, float strength, float eps, float ratio_max,
    __global float4 *layer)                                  /* zero elsewhere (set once) */
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    int p = support[i];
    int f = fill[p];
    /* Surface turned away from the camera by the head's rotation fades out: the warp of the
       reference cannot place it, and its light would land on the background. */
    float nz = rz0 * normal[3 * p] + rz1 * normal[3 * p + 1] + rz2 * normal[3 * p + 2];
    float a = alpha[p] * strength * fclamp((nz - FACING_LO) / (FACING_HI - FACING_LO), 0.0f, 1.0f);
    float3 rel = f >= 0 ? (float3)(relit[3 * f], relit[3 * f + 1], relit[3 * f + 2]) : (float3)(0.0f);
    float3 v;
    if (transfer) {
        float3 r = gain * (rel + eps) * (float3)(inv_amb[3 * p], inv_amb[3 * p + 1], inv_amb[3 * p + 2]);
        v = (float3)(fclamp(r.x, 0.0f, ratio_max), fclamp(r.y, 0.0f, ratio_max), fclamp(r.z, 0.0f, ratio_max));
    } else {
        v = gain * rel;
    }
    layer[p] = (float4)(v, (f >= 0 || !transfer) ? a : 0.0f);
}

__attribute__((always_inline)) inline float4 bilerp4(__global const float4 *img, int cw, int ch, float x, float y)
{
    int x0 = ifloor(x), y0 = ifloor(y);
    float ax = x - (float)x0, ay = y - (float)y0;
    float4 acc = (float4)(0.0f);
    for (int k = 0; k < 4; ++k) {
        int xi = x0 + (k & 1), yi = y0 + (k >> 1);
        float w = ((k & 1) ? ax : 1.0f - ax) * ((k >> 1) ? ay : 1.0f - ay);
        int ok = xi >= 0 && yi >= 0 && xi < cw && yi < ch;
        acc += (ok ? w : 0.0f) * img[ok ? yi * cw + xi : 0];
    }
    return acc;
}

__kernel void warp_composite(
    __global uchar *frame, int frame_w,                 /* (H, W, 3) sRGB, modified in place */
    int bx0, int by0, int bw, int bh,                   /* the box */
    __global const float2 *coarse, int gw, int step,   /* (gh, gw) reference positions (frame px) */
    float ox, float oy,                                 /* the crop's origin in the reference */
    __global const float4 *layer, int cw, int ch,       /* (ch, cw) from build_layer */
    __constant float *decode_lut, __global const uchar *encode_lut, int lut_n, int transfer)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= bw || y >= bh)
        return;
    float cx = ((float)x + (float)step + 0.5f) / (float)step - 0.5f;
    float cy = ((float)y + (float)step + 0.5f) / (float)step - 0.5f;
    int i0 = (int)cx, j0 = (int)cy;     /* cx, cy > 0 */
    float ax = cx - (float)i0, ay = cy - (float)j0;
    float2 c00 = coarse[j0 * gw + i0], c10 = coarse[j0 * gw + i0 + 1];
    float2 c01 = coarse[(j0 + 1) * gw + i0], c11 = coarse[(j0 + 1) * gw + i0 + 1];
    if (c00.x < OUTSIDE_HALF || c10.x < OUTSIDE_HALF || c01.x < OUTSIDE_HALF || c11.x < OUTSIDE_HALF)
        return;
    float2 m = (c00 * (1.0f - ax) + c10 * ax) * (1.0f - ay) + (c01 * (1.0f - ax) + c11 * ax) * ay;
    float4 l = bilerp4(layer, cw, ch, m.x - ox, m.y - oy);
    float a = l.w;
    if (!(a > 0.0f))
        return;
    size_t o = 3 * ((size_t)(by0 + y) * frame_w + (bx0 + x));
    float3 f = (float3)(decode_lut[frame[o]], decode_lut[frame[o + 1]], decode_lut[frame[o + 2]]);
    float3 res = transfer ? f * (1.0f + a * (l.xyz - 1.0f)) : f + a * (l.xyz - f);
    frame[o] = encode(encode_lut, lut_n, res.x);
    frame[o + 1] = encode(encode_lut, lut_n, res.y);
    frame[o + 2] = encode(encode_lut, lut_n, res.z);
}
