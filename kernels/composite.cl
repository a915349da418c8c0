/* The relit face warped into a video frame and composited, in two passes.
 *
 * Every mode is one per-pixel rule in linear light, with f the frame's pixel:
 *     face = (s (f + lift) + k f) r + (1 - s - k) T,        out = f + a (face - f)
 * r the lighting ratio applied to the live pixel, T the bundle's own prediction, s in 0-1 how far
 * the live pixel is trusted, k the share kept as something over the face (MODE_LIVE, step 3; 0
 * elsewhere), a the composited share (feathered mask x strength x facing); lift the ratio's
 * regulariser (MODE_LIVE: eps; 0 in the other modes).
 *
 * build_layer (reference crop, one work item per crop pixel with a > 0) writes (r, s, T, a), and
 * in MODE_LIVE the live light's prediction there: expect = lum E, expect_rgb = E:
 *   MODE_AMBIENT  r = gain (relit + eps) / (ambient + eps), clamped to [0, ratio_max]; s = 1
 *                 (the capture room's light swapped for the target's: the paper's setting);
 *   MODE_PASTE    s = 0, T = gain relit (the relit reference face, the paper's warp);
 *   MODE_LIVE     T = gain relit (the target light, exposure-matched to the live face),
 *                 E = the face under the live light (fitted to the frame), r = T / (E + eps)
 *                 clamped - with lift = eps the trusted face is T (f + eps) / (E + eps): exactly T
 *                 where the live pixel is what the live light predicts, the regulariser biasing
 *                 nothing there (a (T + eps) / (E + eps) ratio lifted T by eps (1 - T / E), most
 *                 where the target darkens what the live light lit); s falls from 1 to 0 where
 *                 the live light leaves the pixel much darker than the target wants (q = lum E / max(lum E, lum T) from Q_HI down to Q_LO: a
 *                 ratio would only amplify noise and cannot bring back detail a shadow hid) or
 *                 near black (lum E / the face's median from D_HI down to D_LO).
 *   with relit / E read through `fill` (crop pixel -> relit frame pixel, -1 = none: the nearest
 *   face pixel fills the feathered fringe).
 * warp_composite (the face's box in the frame, sRGB uint8 RGB, modified in place):
 *   1. the pixel's reference position: bilinear in a coarse inverse map (gh, gw) of float2
 *      reference pixels sampled every `step` frame pixels (one extra grid point on each side of
 *      the box; x < OUTSIDE_HALF marks grid points outside the warp) - inside only when all
 *      four grid points around it are;
 *   2. one bilinear float8 sample of the layer there (zero outside the crop);
 *   3. MODE_LIVE: s drops to 0 where the live pixel is clipped (max channel from CLIP_LO to
 *      CLIP_HI: a saturated pixel carries no ratio) and where it is much darker than the live
 *      light predicts (lum f / lum E from AGREE_HI down to AGREE_LO: a shadow edge the fitted
 *      light draws a pixel off, which a ratio would keep) - unless its colour is not the face's
 *      (the spread of f / E over the three channels, relative to their mean, from FOREIGN_LO up
 *      to FOREIGN_HI: a shadow scales the channels alike, glasses' rims or a strand of hair do
 *      not - those take a share k of f r, without the lift, with s + k up to what the darkness
 *      took, whatever the layer's s was) - and where the live pixel differs from
 *      what the live light predicts by no more than `tau` (relative; the fit's own scatter:
 *      the ratio would only carry the model's error and the camera's noise into the output) -
 *      soft-thresholded (s scaled by (dev - tau) / dev, dev = |lum f / lum E - 1|), so what
 *      the bundle cannot explain (eyes, mouth, expression) passes; the rule above;
 *   4. sRGB encode through the 16k-entry table (as relight.colour.encode_srgb8).
 * Pixels outside the warp keep their bytes.
 * composite_person (region person): warp_composite's face plus the light's change over the rest
 * of the person, in one pass over the face's box and the person's (see the kernel).
 */

/* The rules' thresholds, named once in relight.kernels.compositor and given as build options
   (Compositor: -D NAME=value): FACING (FACING_LO, FACING_HI: the camera-facing component of a
   turned normal below which the face fades out, above which it is whole), TRUST_RATIO (Q_LO,
   Q_HI), TRUST_DARK (D_LO, D_HI), CLIP_RAMP (CLIP_LO, CLIP_HI), AGREE_RAMP (AGREE_LO, AGREE_HI),
   FOREIGN_RAMP (FOREIGN_LO, FOREIGN_HI), CHROMA_FLOOR, FOREIGN_NOISE and GATE_HI (the person's
   share above which the face's composite is whole: the solid matte's); OUTSIDE_HALF (reference
   positions below it mark grid points outside the warp) and the layer modes' codes
   (MODE_AMBIENT, MODE_PASTE, MODE_LIVE: compositor.LAYER_MODES). */
#if !defined(FACING_LO) || !defined(AGREE_LO) || !defined(FOREIGN_LO) || !defined(GATE_HI) || \
    !defined(OUTSIDE_HALF) || !defined(MODE_LIVE)
#error "build composite.cl through relight.kernels.compositor.Compositor: it defines the rules' thresholds"
#endif

/* PoCL 3.0 calls its math builtins (floor, clamp, fmax, ...) out of line, spilling vector registers
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

__attribute__((always_inline)) inline float fmx(float a, float b)
{
    return a > b ? a : b;
}

__attribute__((always_inline)) inline float lum3(float3 c)
{
    return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z;
}

__attribute__((always_inline)) inline uchar encode(__global const uchar *lut, int n, float v)
{
    float i = fclamp(v * (float)n + 0.5f, 0.0f, (float)n);
    return lut[(int)i];
}

__attribute__((always_inline)) inline float3 read3(__global const float *img, int f)
{
    return f >= 0 ? (float3)(img[3 * f], img[3 * f + 1], img[3 * f + 2]) : (float3)(0.0f);
}

/* One crop pixel of the layer (see the file comment). */
__kernel void build_layer(
    __global const float *relit, __global const float *live,  /* relit frames (.., 3): target, live light */
    __global const int *fill,                                  /* (ch * cw,) indices */
    __global const float *inv_amb, __global const float *alpha,
    __global const float *normal, float rz0, float rz1, float rz2, /* (ch * cw, 3); the head rotation's z row */
    __global const int *support, int n,                      /* the crop pixels with alpha > 0 */
    int mode, float gain, float strength, float eps, float ratio_max, float live_median,
    __global float8 *layer,                                  /* zero elsewhere (set once) */
    __global float *expect,                                  /* MODE_LIVE: lum E (live units) */
    __global float4 *expect_rgb)                             /* MODE_LIVE: E (its colour: read nearest) */
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    int p = support[i];
    int f = fill[p];
    /* Surface the head's rotation turns away from the camera, past where the reference saw it,
       fades out: the warp of the reference cannot place it, and its light would land on the
       background (relight.kernels.compositor.facing_weight). */
    float nz = rz0 * normal[3 * p] + rz1 * normal[3 * p + 1] + rz2 * normal[3 * p + 2];
    nz += fmx(FACING_HI - normal[3 * p + 2], 0.0f);
    float a = alpha[p] * strength * fclamp((nz - FACING_LO) / (FACING_HI - FACING_LO), 0.0f, 1.0f);
    float3 rel = read3(relit, f);
    float3 r = (float3)(0.0f), t = (float3)(0.0f);
    float s = 0.0f;
    if (mode == MODE_AMBIENT) {
        float3 q = gain * (rel + eps) * (float3)(inv_amb[3 * p], inv_amb[3 * p + 1], inv_amb[3 * p + 2]);
        r = (float3)(fclamp(q.x, 0.0f, ratio_max), fclamp(q.y, 0.0f, ratio_max), fclamp(q.z, 0.0f, ratio_max));
        s = 1.0f;
        if (f < 0)
            a = 0.0f;
    } else if (mode == MODE_PASTE) {
        t = gain * rel;
    } else {
        float3 e = read3(live, f);
        t = gain * rel;
        float3 q = t / (e + eps);
        r = (float3)(fclamp(q.x, 0.0f, ratio_max), fclamp(q.y, 0.0f, ratio_max), fclamp(q.z, 0.0f, ratio_max));
        float le = lum3(e), lt = lum3(t);
        float share = le / fmx(fmx(le, lt), 1e-12f);
        float dark = le / fmx(live_median, 1e-12f);
        s = fclamp((share - Q_LO) / (Q_HI - Q_LO), 0.0f, 1.0f) * fclamp((dark - D_LO) / (D_HI - D_LO), 0.0f, 1.0f);
        expect[p] = le;
        expect_rgb[p] = (float4)(e, 0.0f);
        if (f < 0)
            a = 0.0f;
    }
    layer[p] = (float8)(r, s, t, a);
}

__attribute__((always_inline)) inline float8 bilerp8(__global const float8 *img, int cw, int ch, float x, float y)
{
    int x0 = ifloor(x), y0 = ifloor(y);
    float ax = x - (float)x0, ay = y - (float)y0;
    float8 acc = (float8)(0.0f);
    for (int k = 0; k < 4; ++k) {
        int xi = x0 + (k & 1), yi = y0 + (k >> 1);
        float w = ((k & 1) ? ax : 1.0f - ax) * ((k >> 1) ? ay : 1.0f - ay);
        int ok = xi >= 0 && yi >= 0 && xi < cw && yi < ch;
        acc += (ok ? w : 0.0f) * img[ok ? yi * cw + xi : 0];
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

/* The nearest texel's colour (E's colour is smooth: one read where the bilinear takes four). */
__attribute__((always_inline)) inline float3 nearest3(__global const float4 *img, int cw, int ch, float x, float y)
{
    int xi = ifloor(x + 0.5f), yi = ifloor(y + 0.5f);
    int ok = xi >= 0 && yi >= 0 && xi < cw && yi < ch;
    return ok ? img[yi * cw + xi].xyz : (float3)(0.0f);
}

/* The face composited at position (x, y) relative to the face's box (frame px, x, y >= 0) on
   the frame's pixel f (linear): 1 and *res = f + a (face - f) where the face reaches (a > 0),
   else 0 (the pixel keeps its bytes). Steps 1-3 of the file comment. */
__attribute__((always_inline)) inline int face_at(
    float x, float y, float3 f, __global const float2 *coarse, int gw, int step, float ox, float oy,
    __global const float8 *layer, int cw, int ch, __global const float *expect,
    __global const float4 *expect_rgb, int mode, float tau,
    float lift, float3 *res, float *a_out, float3 *gain_out, float3 *off_out)
{
    float cx = (x + (float)step + 0.5f) / (float)step - 0.5f;
    float cy = (y + (float)step + 0.5f) / (float)step - 0.5f;
    int i0 = (int)cx, j0 = (int)cy;     /* cx, cy > 0 */
    float ax = cx - (float)i0, ay = cy - (float)j0;
    float2 c00 = coarse[j0 * gw + i0], c10 = coarse[j0 * gw + i0 + 1];
    float2 c01 = coarse[(j0 + 1) * gw + i0], c11 = coarse[(j0 + 1) * gw + i0 + 1];
    if (c00.x < OUTSIDE_HALF || c10.x < OUTSIDE_HALF || c01.x < OUTSIDE_HALF || c11.x < OUTSIDE_HALF)
        return 0;
    float2 m = (c00 * (1.0f - ax) + c10 * ax) * (1.0f - ay) + (c01 * (1.0f - ax) + c11 * ax) * ay;
    float8 l = bilerp8(layer, cw, ch, m.x - ox, m.y - oy);
    float a = l.s7;
    if (!(a > 0.0f))
        return 0;
    float s = l.s3, kf = 0.0f;
    if (mode == MODE_LIVE) {
        float e = bilerp1(expect, cw, ch, m.x - ox, m.y - oy);
        float agree = lum3(f) / fmx(e, 1e-12f);
        float dark = fclamp((agree - AGREE_LO) / (AGREE_HI - AGREE_LO), 0.0f, 1.0f);
        if (s > 0.0f) {
            s *= 1.0f - fclamp((fmx(f.x, fmx(f.y, f.z)) - CLIP_LO) / (CLIP_HI - CLIP_LO), 0.0f, 1.0f);
            s *= dark;
            float dev = fabs(agree - 1.0f);
            s *= dev > tau ? (dev - tau) / dev : 0.0f;
        }
        /* darker than the live light predicts, and of another colour than the face there: not a
           shadow (one scales the three channels alike) but something over the face - glasses'
           rims, a strand of hair - kept as it is, taking the ratio, as far as the darkness took
           its trust */
        if (dark < 1.0f) {  /* (k is 0 elsewhere) */
            float3 ec = nearest3(expect_rgb, cw, ch, m.x - ox, m.y - oy);
            float floor_e = CHROMA_FLOOR * e;
            float3 q = (f + FOREIGN_NOISE) / ((float3)(fmx(fmx(ec.x, floor_e), 0.0f), fmx(fmx(ec.y, floor_e), 0.0f),
                                                       fmx(fmx(ec.z, floor_e), 0.0f)) + FOREIGN_NOISE);
            float qm = (q.x + q.y + q.z) * (1.0f / 3.0f);
            float spread = fmx(fmx(fabs(q.x - qm), fabs(q.y - qm)), fabs(q.z - qm)) / fmx(qm, 1e-12f);
            kf = fmx(fclamp((spread - FOREIGN_LO) / (FOREIGN_HI - FOREIGN_LO), 0.0f, 1.0f) * (1.0f - dark) - s,
                     0.0f);
        }
    }
    /* (what is kept as foreign takes the ratio without the lift: its regulariser would brighten
       a dark object by eps r, more than its own light) */
    float3 face = (s * (f + lift) + kf * f) * l.s012 + (1.0f - s - kf) * l.s456;
    *res = f + a * (face - f);
    *a_out = a;
    /* the same as res = gain f + offset (the light field's affine form) */
    *gain_out = 1.0f - a + a * (s + kf) * l.s012;
    *off_out = a * (s * lift * l.s012 + (1.0f - s - kf) * l.s456);
    return 1;
}

__attribute__((always_inline)) inline float3 decode3(__constant float *lut, __global const uchar *px)
{
    return (float3)(lut[px[0]], lut[px[1]], lut[px[2]]);
}

__attribute__((always_inline)) inline void encode3(__global const uchar *lut, int n, __global uchar *px, float3 v)
{
    px[0] = encode(lut, n, v.x);
    px[1] = encode(lut, n, v.y);
    px[2] = encode(lut, n, v.z);
}

__kernel void warp_composite(
    __global uchar *frame, int frame_w,                 /* (H, W, 3) sRGB, modified in place */
    int bx0, int by0, int bw, int bh,                   /* the box */
    __global const float2 *coarse, int gw, int step,   /* (gh, gw) reference positions (frame px) */
    float ox, float oy,                                 /* the crop's origin in the reference */
    __global const float8 *layer, int cw, int ch,       /* (ch, cw) from build_layer */
    __global const float *expect, __global const float4 *expect_rgb,  /* (ch, cw) from build_layer (MODE_LIVE) */
    __global const uchar *groups,                       /* per work-group: may the face reach it */
    __constant float *decode_lut, __global const uchar *encode_lut, int lut_n, int mode, float tau, float lift)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= bw || y >= bh || !groups[get_group_id(1) * get_num_groups(0) + get_group_id(0)])
        return;
    size_t o = 3 * ((size_t)(by0 + y) * frame_w + (bx0 + x));
    float3 f = decode3(decode_lut, frame + o), res, gn, of;
    float a;
    if (face_at((float)x, (float)y, f, coarse, gw, step, ox, oy, layer, cw, ch, expect, expect_rgb, mode, tau, lift,
                &res, &a, &gn, &of))
        encode3(encode_lut, lut_n, frame + o, res);
}

/* The whole person in one pass (region person, relight.engine.head_light): over a box of an image
 * whose pixel (i, j) sits at frame position (X, Y) = ((i + 0.5) scx - 0.5, (j + 0.5) scy - 0.5)
 * - the frame itself (scales 1) or a smaller copy of it (scales > 1) -
 *     out = f + a (face - f) + f w G,    w = max(m, a) (1 - a), counted where w > floor,
 * the face's composite as warp_composite makes it inside the face's box (fx0, fy0, fw, fh: frame
 * px; a = 0 outside it), G = rho - 1 the light's change over the person and m its share: the
 * float4 (G, m) of a grid (gh, gw) over the frame or a box of it, bilinear at the pixel's centre
 * (sx, sy: grid cells per frame px; edges replicated; gw = 0: none, the face alone) - the image's
 * positions moved by (gox, goy) there (an image of a box of the frame: the box's corner; a grid of
 * a box: less its corner in frame px). With ``gate`` (a matte the frame path trusts around this
 * face) the face's composite is held to the person too: its share a, and its change, scaled by
 * k = m from floor up to GATE_HI (a face's warp reaching past the jaw onto the wall leaves the wall
 * as it was); without, the face's composite is never scaled by the person's share. */
/* composite_person's pixel: the linear value *res of the pixel at (i, j) of the image (frame
   position (X, Y), its value f) and whether it changed (see composite_person). */
__attribute__((always_inline)) inline int person_at(
    int x, int y, int here, float X, float Y, float3 f, float3 *res,
    int fx0, int fy0, int fw, int fh,
    __global const float2 *coarse, int cgw, int step, float ox, float oy,
    __global const float8 *layer, int cw, int ch, __global const float *expect, __global const float4 *expect_rgb,
    __global const float4 *person, int gw, int gh, float sx, float sy, float gox, float goy, float floor_w,
    int gate, int mode, float tau, float lift, float3 *gain, float3 *off)
{
    float a = 0.0f;
    int changed = 0;
    *res = f;
    *gain = (float3)(1.0f);
    *off = (float3)(0.0f);
    float fx = X - (float)fx0, fy = Y - (float)fy0;
    if ((here & 1) && fx >= 0.0f && fy >= 0.0f && fx <= (float)(fw - 1) && fy <= (float)(fh - 1))
        changed = face_at(fx, fy, f, coarse, cgw, step, ox, oy, layer, cw, ch, expect, expect_rgb, mode, tau, lift,
                          res, &a, gain, off);
    if (gw > 0) {
        float gx = (X + gox + 0.5f) * sx - 0.5f, gy = (Y + goy + 0.5f) * sy - 0.5f;
        int x0 = ifloor(gx), y0 = ifloor(gy);
        float ax = gx - (float)x0, ay = gy - (float)y0;
        int xa = x0 < 0 ? 0 : (x0 > gw - 1 ? gw - 1 : x0), xb = x0 + 1 < 0 ? 0 : (x0 + 1 > gw - 1 ? gw - 1 : x0 + 1);
        int ya = y0 < 0 ? 0 : (y0 > gh - 1 ? gh - 1 : y0), yb = y0 + 1 < 0 ? 0 : (y0 + 1 > gh - 1 ? gh - 1 : y0 + 1);
        float4 g = (person[ya * gw + xa] * (1.0f - ax) + person[ya * gw + xb] * ax) * (1.0f - ay)
                 + (person[yb * gw + xa] * (1.0f - ax) + person[yb * gw + xb] * ax) * ay;
        if (gate && a > 0.0f) {
            /* the face's composite held to the person where the matte is trusted */
            float k = fclamp((g.w - floor_w) / (GATE_HI - floor_w), 0.0f, 1.0f);
            *res = f + k * (*res - f);
            *gain = 1.0f + k * (*gain - 1.0f);
            *off *= k;
            a *= k;
        }
        float w = fmx(g.w, a) * (1.0f - a);
        if (w > floor_w) {
            *res += f * w * g.xyz;
            *gain += w * g.xyz;
            changed = 1;
        }
    }
    return changed;
}

__kernel void composite_person(
    __global uchar *img, int img_w, int bx0, int by0, int bw, int bh, float scx, float scy,
    int fx0, int fy0, int fw, int fh,
    __global const float2 *coarse, int cgw, int step, float ox, float oy,
    __global const float8 *layer, int cw, int ch, __global const float *expect, __global const float4 *expect_rgb,
    __global const float4 *person, int gw, int gh, float sx, float sy, float gox, float goy, float floor_w,
    int gate, __global const uchar *groups,
    __constant float *decode_lut, __global const uchar *encode_lut, int lut_n, int mode, float tau, float lift)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= bw || y >= bh)
        return;
    /* what may change in this work-group (bit 0 the face, bit 1 the person: one flag per group,
       no divergence): nothing - the pixels keep their bytes */
    int here = groups[get_group_id(1) * get_num_groups(0) + get_group_id(0)];
    if (!here)
        return;
    int i = bx0 + x, j = by0 + y;
    float X = ((float)i + 0.5f) * scx - 0.5f, Y = ((float)j + 0.5f) * scy - 0.5f;
    size_t o = 3 * ((size_t)j * img_w + i);
    float3 f = decode3(decode_lut, img + o), res, gn, of;
    if (person_at(x, y, here, X, Y, f, &res, fx0, fy0, fw, fh, coarse, cgw, step, ox, oy, layer, cw, ch, expect,
                  expect_rgb, person, gw, gh, sx, sy, gox, goy, floor_w, gate, mode, tau, lift, &gn, &of))
        encode3(encode_lut, lut_n, img + o, res);
}

/* The light's change of composite_person as a light field (relight.engine.field): over the box
   of a small copy of the frame, per pixel (the small copy's uchar sRGB decoded) where it changes:
   affine = 0: ((res + GAIN_EPS) / (f + GAIN_EPS), 1, 0, 0) - a gain per channel, clamped to
   gain_max; affine = 1: (G, 1, B, 0) with res = G f + B (the composite's own split: the share of
   the live pixel kept, times its ratio, and what the bundle's prediction adds); where it does
   not: (1, 1, 1, 0, 0, 0, 0, 0). */
__kernel void person_gain(
    __global const uchar *img, int img_w, int bx0, int by0, int bw, int bh, float scx, float scy,
    int fx0, int fy0, int fw, int fh,
    __global const float2 *coarse, int cgw, int step, float ox, float oy,
    __global const float8 *layer, int cw, int ch, __global const float *expect, __global const float4 *expect_rgb,
    __global const float4 *person, int gw, int gh, float sx, float sy, float gox, float goy, float floor_w,
    int gate, __global const uchar *groups,
    __constant float *decode_lut, int mode, float tau, float lift, float gain_max, int affine,
    __global float8 *gain)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= bw || y >= bh)
        return;
    int here = groups[get_group_id(1) * get_num_groups(0) + get_group_id(0)];
    float8 g = (float8)(1.0f, 1.0f, 1.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f);
    if (here) {
        int i = bx0 + x, j = by0 + y;
        float X = ((float)i + 0.5f) * scx - 0.5f, Y = ((float)j + 0.5f) * scy - 0.5f;
        size_t o = 3 * ((size_t)j * img_w + i);
        float3 f = decode3(decode_lut, img + o), res, gn, of;
        if (person_at(x, y, here, X, Y, f, &res, fx0, fy0, fw, fh, coarse, cgw, step, ox, oy, layer, cw, ch,
                      expect, expect_rgb, person, gw, gh, sx, sy, gox, goy, floor_w, gate, mode, tau, lift, &gn,
                      &of)) {
            if (affine) {
                g = (float8)(gn, 1.0f, of, 0.0f);
            } else {
                float3 q = (res + GAIN_EPS) / (f + GAIN_EPS);
                g = (float8)(fclamp(q.x, 0.0f, gain_max), fclamp(q.y, 0.0f, gain_max), fclamp(q.z, 0.0f, gain_max),
                             1.0f, 0.0f, 0.0f, 0.0f, 0.0f);
            }
        }
    }
    gain[(size_t)y * bw + x] = g;
}

/* One channel's change G f + B (linear) as a map of its sRGB code x (0-255): out = k x + n, the
   change linearised at x - k = G dec'(x) / dec'(e) (the encode curve's slope is the inverse of the
   decode curve's at e = enc(G dec(x) + B)), bounded by SLOPE_MAX; n makes it exact at x. Tables:
   ``dslope`` the decode curve's slope at each code (interpolated between), ``encf`` the encode
   curve as float codes at enc_n + 1 steps of linear light (interpolated). */
__attribute__((always_inline)) inline float2 code_line(uchar code, float g, float b, __constant float *decode_lut,
                                                       __global const float *dslope, __global const float *encf,
                                                       int enc_n)
{
    float v = fclamp(g * decode_lut[code] + b, 0.0f, 1.0f) * (float)enc_n;
    int k0 = (int)v;
    k0 = k0 > enc_n - 1 ? enc_n - 1 : k0;
    float e = encf[k0] + (v - (float)k0) * (encf[k0 + 1] - encf[k0]);
    int c0 = (int)e;
    c0 = c0 > 254 ? 254 : c0;
    float se = dslope[c0] + (e - (float)c0) * (dslope[c0 + 1] - dslope[c0]);
    float k = fclamp(g * dslope[code] / fmx(se, 1e-12f), 0.0f, SLOPE_MAX);
    return (float2)(k, e - k * (float)code);
}

/* person_gain's (G, cover, B) of each cell of the small copy (affine = 1), in place in ``cells``
   (bh * bw float8), as the light field's maps of the frame's codes (``out``, bh * bw * 32 floats:
   the tangent map - three rows of 4 -, the chord map - three rows of 4 -, the cover, the knee in
   the frame's codes, four zeros):
   per channel code_line at the small copy's own code x_c (its pixel at (bx0 + x, by0 + y) of
   ``img``): the tangent k x + n, and the chord through black and the tangent at the knee
   q = x_c - KNEE_GAP, x (k q + n) / q (what a pixel darker than the knee takes: field.cl), each
   composed with the frame's matrices - ``to_rgb`` its
   codes -> R'G'B' codes, ``to_ycc`` back (rows of 4; identities for an RGB frame). A cell that
   changes nothing maps to itself both ways. */
__attribute__((always_inline)) inline void compose(__global float *m, const float *kk, const float *nn,
                                                   const float *r, const float *qq)
{
    for (int row = 0; row < 3; ++row) {
        float t = qq[4 * row + 3];
        for (int col = 0; col < 3; ++col) {
            float acc = 0.0f;
            for (int j = 0; j < 3; ++j)
                acc += qq[4 * row + j] * kk[j] * r[4 * j + col];
            m[4 * row + col] = acc;
        }
        for (int j = 0; j < 3; ++j)
            t += qq[4 * row + j] * (kk[j] * r[4 * j + 3] + nn[j]);
        m[4 * row + 3] = t;
    }
}

__kernel void field_cells(
    __global const uchar *img, int img_w, int bx0, int by0, int bw, int bh, __global const float8 *cells,
    __constant float *decode_lut, __global const float *dslope, __global const float *encf, int enc_n,
    float16 to_rgb, float16 to_ycc, __global float *out)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= bw || y >= bh)
        return;
    size_t q = (size_t)y * bw + x;
    float8 c = cells[q];
    __global float *m = out + 32 * q;
    __global const uchar *px = img + 3 * ((size_t)(by0 + y) * img_w + bx0 + x);
    for (int k = 0; k < 32; ++k)
        m[k] = (k == 0 || k == 5 || k == 10 || k == 12 || k == 17 || k == 22) ? 1.0f : 0.0f;
    m[24] = c.s3;
    if (!(c.s3 > 0.0f))
        return;
    float2 l0 = code_line(px[0], c.s0, c.s4, decode_lut, dslope, encf, enc_n);
    float2 l1 = code_line(px[1], c.s1, c.s5, decode_lut, dslope, encf, enc_n);
    float2 l2 = code_line(px[2], c.s2, c.s6, decode_lut, dslope, encf, enc_n);
    float kk[3] = {l0.x, l1.x, l2.x}, nn[3] = {l0.y, l1.y, l2.y};
    /* the knee: KNEE_GAP codes below the cell's colour (no chord for a cell darker than that: its
       chord is its tangent and no pixel is below its knee) */
    float kn[3], ch[3];
    float2 ln[3] = {l0, l1, l2};
    for (int j = 0; j < 3; ++j) {
        float q = (float)px[j] - KNEE_GAP;
        kn[j] = q > 0.0f ? q : -1.0f;
        ch[j] = q > 0.0f ? fclamp((ln[j].x * q + ln[j].y) / q, 0.0f, SLOPE_MAX) : ln[j].x;
    }
    float cn[3] = {0.0f, 0.0f, 0.0f};
    for (int j = 0; j < 3; ++j)
        cn[j] = kn[j] > 0.0f ? 0.0f : ln[j].y;  /* (a chord that is the tangent keeps its offset) */
    float r[12] = {to_rgb.s0, to_rgb.s1, to_rgb.s2, to_rgb.s3, to_rgb.s4, to_rgb.s5, to_rgb.s6, to_rgb.s7,
                   to_rgb.s8, to_rgb.s9, to_rgb.sa, to_rgb.sb};
    float qq[12] = {to_ycc.s0, to_ycc.s1, to_ycc.s2, to_ycc.s3, to_ycc.s4, to_ycc.s5, to_ycc.s6, to_ycc.s7,
                    to_ycc.s8, to_ycc.s9, to_ycc.sa, to_ycc.sb};
    compose(m, kk, nn, r, qq);
    compose(m + 12, ch, cn, r, qq);
    for (int row = 0; row < 3; ++row)  /* the knee in the frame's codes */
        m[25 + row] = qq[4 * row] * kn[0] + qq[4 * row + 1] * kn[1] + qq[4 * row + 2] * kn[2] + qq[4 * row + 3];
}
