/* warp_composite: the relit face warped into a video frame and composited, in one pass.
 *
 * For each pixel of the face's box in the frame (sRGB uint8, RGB, row-major, modified in place):
 *   1. its reference position: bilinear in a coarse inverse map (gh, gw) of float2 reference
 *      pixels sampled every `step` frame pixels (one extra grid point on each side of the box;
 *      x < OUTSIDE_HALF marks grid points outside the warp) - a pixel is inside the warp only
 *      when all four grid points around it are;
 *   2. bilinear samples at that reference position (crop pixels, zero outside the crop) of
 *      alpha (the feathered face mask), the relit face read through `fill` (crop pixel -> index
 *      into the relit frame, -1 = none: nearest face pixels fill the feathered fringe) and, for
 *      transfer, 1 / (reference ambient + eps);
 *   3. transfer: out = frame * (1 + a (clamp(gain (relit + eps) inv_amb, 0, ratio_max) - 1))
 *      paste:    out = frame + a (gain relit - frame),     a = alpha * strength;
 *   4. sRGB encode through the 16k-entry table (as relight.colour.encode_srgb8).
 * Pixels outside the warp keep their bytes.
 */

#define OUTSIDE_HALF (-5.0e3f)

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

/* Bilinear sample of a (ch, cw, 3) image - or, with fill, of the relit frame's pixel fill[p] -
   at crop position (x, y); taps outside the crop or without a fill pixel count zero. */
__attribute__((always_inline)) inline float3 bilerp3(__global const float *img, __global const int *fill, int cw, int ch, float x, float y,
                      int use_fill)
{
    int x0 = ifloor(x), y0 = ifloor(y);
    float ax = x - (float)x0, ay = y - (float)y0;
    float3 acc = (float3)(0.0f);
    for (int k = 0; k < 4; ++k) {
        int xi = x0 + (k & 1), yi = y0 + (k >> 1);
        float w = ((k & 1) ? ax : 1.0f - ax) * ((k >> 1) ? ay : 1.0f - ay);
        int ok = xi >= 0 && yi >= 0 && xi < cw && yi < ch;
        int src = ok ? yi * cw + xi : 0;
        if (use_fill) {
            int f = fill[src];
            ok = ok && f >= 0;
            src = ok ? f : 0;
        }
        w = ok ? w : 0.0f;
        acc += w * (float3)(img[3 * src], img[3 * src + 1], img[3 * src + 2]);
    }
    return acc;
}

__attribute__((always_inline)) inline float bilerp1(__global const float *img, int cw, int ch, float x, float y)
{
    int x0 = ifloor(x), y0 = ifloor(y);
    float ax = x - (float)x0, ay = y - (float)y0;
    float acc = 0.0f;
    for (int k = 0; k < 4; ++k) {
        int xi = x0 + (k & 1), yi = y0 + (k >> 1);
        float w = ((k & 1) ? ax : 1.0f - ax) * ((k >> 1) ? ay : 1.0f - ay);
        int ok = xi >= 0 && yi >= 0 && xi < cw && yi < ch;
        acc += (ok ? w : 0.0f) * img[ok ? yi * cw + xi : 0];
    }
    return acc;
}

__attribute__((always_inline)) inline uchar encode(__global const uchar *lut, int n, float v)
{
    float i = fclamp(v * (float)n + 0.5f, 0.0f, (float)n);
    return lut[(int)i];
}

/* One pixel of the box (see the file comment). */
__attribute__((always_inline)) inline void composite_pixel(
    int x, int y, __global uchar *frame, int frame_w, int bx0, int by0,
    __global const float2 *coarse, int gw, int step, float ox, float oy,
    __global const float *alpha, int cw, int ch, __global const float *relit, __global const int *fill,
    __global const float *inv_amb, __constant float *decode_lut, __global const uchar *encode_lut, int lut_n,
    int transfer, float gain, float strength, float eps, float ratio_max)
{
    float cx = ((float)x + (float)step + 0.5f) / (float)step - 0.5f;
    float cy = ((float)y + (float)step + 0.5f) / (float)step - 0.5f;
    int i0 = (int)cx, j0 = (int)cy;     /* cx, cy > 0 */
    float ax = cx - (float)i0, ay = cy - (float)j0;
    float2 c00 = coarse[j0 * gw + i0], c10 = coarse[j0 * gw + i0 + 1];
    float2 c01 = coarse[(j0 + 1) * gw + i0], c11 = coarse[(j0 + 1) * gw + i0 + 1];
    if (c00.x < OUTSIDE_HALF || c10.x < OUTSIDE_HALF || c01.x < OUTSIDE_HALF || c11.x < OUTSIDE_HALF)
        return;
    float2 m = (c00 * (1.0f - ax) + c10 * ax) * (1.0f - ay) + (c01 * (1.0f - ax) + c11 * ax) * ay;
    float rx = m.x - ox, ry = m.y - oy;
    float a = bilerp1(alpha, cw, ch, rx, ry) * strength;
    if (!(a > 0.0f))
        return;
    float3 rel = bilerp3(relit, fill, cw, ch, rx, ry, 1);
    size_t o = 3 * ((size_t)(by0 + y) * frame_w + (bx0 + x));
    float3 f = (float3)(decode_lut[frame[o]], decode_lut[frame[o + 1]], decode_lut[frame[o + 2]]);
    float3 res;
    if (transfer) {
        float3 inv = bilerp3(inv_amb, fill, cw, ch, rx, ry, 0);
        float3 r = gain * (rel + eps) * inv;
        r = (float3)(fclamp(r.x, 0.0f, ratio_max), fclamp(r.y, 0.0f, ratio_max), fclamp(r.z, 0.0f, ratio_max));
        res = f * (1.0f + a * (r - 1.0f));
    } else {
        res = f + a * (gain * rel - f);
    }
    frame[o] = encode(encode_lut, lut_n, res.x);
    frame[o + 1] = encode(encode_lut, lut_n, res.y);
    frame[o + 2] = encode(encode_lut, lut_n, res.z);
}

/* Each work item: RUN consecutive pixels of one row (few, large work-groups: PoCL's cost per
   work-group dominated with one pixel per work item - measured 8 ms against ~1 ms). */
#define RUN 32

__kernel void warp_composite(
    __global uchar *frame, int frame_w,                 /* (H, W, 3) sRGB, modified in place */
    int bx0, int by0, int bw, int bh,                   /* the box */
    __global const float2 *coarse, int gw, int step,   /* (gh, gw) reference positions (frame px) */
    float ox, float oy,                                 /* the crop's origin in the reference */
    __global const float *alpha, int cw, int ch,        /* (ch, cw) */
    __global const float *relit, __global const int *fill, /* relit frame (.., 3); (ch, cw) indices */
    __global const float *inv_amb,                      /* (ch, cw, 3) */
    __constant float *decode_lut, __global const uchar *encode_lut, int lut_n,
    int transfer, float gain, float strength, float eps, float ratio_max)
{
    int y = get_global_id(1);
    int xs = get_global_id(0) * RUN;
    if (y >= bh)
        return;
    int xe = xs + RUN < bw ? xs + RUN : bw;
    for (int x = xs; x < xe; ++x)
        composite_pixel(x, y, frame, frame_w, bx0, by0, coarse, gw, step, ox, oy, alpha, cw, ch, relit, fill,
                        inv_amb, decode_lut, encode_lut, lut_n, transfer, gain, strength, eps, ratio_max);
}
