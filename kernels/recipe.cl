/* Texel rows from a bundle's recipe (relight.kernels.recipe; NumPy twin:
 * relight.kernels.recipe.texel_rows).
 *
 * texel_rows: per pixel, a few map texels (a sun, a point light) made again from the stored
 *   samples and fits exactly as relight.pipeline.shading_fit.model_maps made them: the shading
 *   model at the triangles' vertices (visibility from the horizon table), the vertices' values
 *   (sample minus the trusted model; beyond the hull the model plus what it leaves of the
 *   nearest samples), visibility-aware interpolation, the trusted model added back, and the
 *   thin-plate spline (in the samples' code domain, capped at the triangle's brightest sample)
 *   blended in by the pixel's weight. Written as halves into rows (slot, 3, P).
 */
#include "common.h"

#define MAX_POS 112
#define MAX_MV 96
#define MAX_T 8

/* Smoothed visibility at one position: the mean over its 3x3 texel neighbourhood (az: x, y =
 * horizon columns, z = blend, w = elevation, >= 4 for straight at the camera). hz: the pixel's
 * horizon codes, or NULL with a constant horizon elevation elev_h. */
inline float smooth_vis(__global const float4 *az, __global const uchar *hz, __constant float *elevation,
                        float elev_h, float inv_soft)
{
    float acc = 0.0f;
    for (int j = 0; j < 9; ++j) {
        float4 a = az[j];
        float v = 1.0f;
        if (a.w < 4.0f) {
            float e = elev_h;
            if (hz)
                e = mix(elevation[hz[(int)a.x]], elevation[hz[(int)a.y]], a.z);
            v = clamp(0.5f + (a.w - e) * inv_soft, 0.0f, 1.0f);
        }
        acc += v;
    }
    return acc * (1.0f / 9.0f);
}

inline float lobe_at(float3 n, float3 l, int spec_exp)
{
    float nl = dot(n, l);
    float3 h = l + (float3)(0.0f, 0.0f, 1.0f);
    float hn = length(h);
    float nh = hn > 1e-6f ? fmax(dot(n, h) / hn, 0.0f) : 0.0f;
    return nl > 0.0f ? ipow(nh, spec_exp) : 0.0f;
}

__kernel void texel_rows(
    __global const uchar *codes, int n_samples, int n_pix,     /* (K, P, 3) sample codes */
    __global const float *scale,                               /* (P, 3) their scale */
    __constant float *decode,                                  /* (256,) code -> (q / 255) ** (1 / gamma) */
    __global const float4 *normal,                             /* (P,) */
    __global const uchar *horizon, int n_az, int use_vis,      /* (P, n_az) elevation codes */
    __constant float *elevation,                               /* (256,) code -> horizon elevation */
    __global const float4 *albedo, __global const float4 *spec,
    __global const float *trust, __global const float *blend,  /* (P,) each */
    __global const float4 *pos_az, int n_pos,                  /* (n_pos, 9) visibility positions */
    __global const float4 *mv_dir,                             /* (n_mv,) model vertices: dir, w = position */
    __global const int4 *mv_kind,                              /* x: sample id, -1 virtual, -2 black; y, z, w: carry */
    __global const float4 *mv_carry, int n_mv,                 /*    model vertices (-1 none) and their weights */
    __global const float4 *t_dir,                              /* (n,) texels: dir, w = position */
    __global const int4 *t_vert,                               /* x, y, z model vertices (-1 black), w spline row */
    __global const float4 *t_wt,                               /* barycentric weights */
    __global const int4 *t_corner, int n_tex,                  /* corner sample ids (spline cap) */
    __global const float *spline_w,                            /* (rows, K) spline weights, code domain */
    int trend, int use_spline, int spec_exp, float inv_soft, float open_elev,
    __global const int *slots, __global half *rows)            /* out: rows[(slot * 3 + c) * P + p] */
{
    int p = get_global_id(0);
    if (p >= n_pix)
        return;
    float3 n = normal[p].xyz;
    float tr = trust[p];
    int open_sky = tr < 0.5f;
    float3 alb = albedo[p].xyz, spc = spec[p].xyz;
    __global const uchar *hz = horizon + (size_t)p * n_az;
    float vis_m[MAX_POS], vis_i[MAX_POS];
    for (int i = 0; i < n_pos; ++i) {
        __global const float4 *az = pos_az + i * 9;
        vis_m[i] = (use_vis && !open_sky) ? smooth_vis(az, hz, elevation, 0.0f, inv_soft) : 1.0f;
        vis_i[i] = !use_vis ? 1.0f : open_sky ? smooth_vis(az, 0, elevation, open_elev, inv_soft) : vis_m[i];
    }
    float3 model[MAX_MV], val[MAX_MV];
    for (int m = 0; m < n_mv; ++m) {
        float4 d = mv_dir[m];
        float3 l = d.xyz;
        float vm = vis_m[(int)d.w];
        model[m] = (alb * fmax(dot(n, l), 0.0f) + spc * lobe_at(n, l, spec_exp)) * vm;
        int4 kind = mv_kind[m];
        if (kind.x == -2) {  /* a black light (no extrapolation beyond the hull) */
            val[m] = (float3)(0.0f);
        } else if (kind.x >= 0) {
            __global const uchar *c = codes + ((size_t)kind.x * n_pix + p) * 3;
            float3 x = (float3)(decode[c[0]], decode[c[1]], decode[c[2]]) * vload3(p, scale);
            val[m] = trend ? x - tr * model[m] : x;
        } else {
            /* what the model leaves of the nearest samples: x - model = val - (1 - trust) x model */
            float keep = trend ? 1.0f - tr : 1.0f;
            float4 cw = mv_carry[m];
            float3 carried = (float3)(0.0f);
            if (kind.y >= 0) carried += cw.x * fmax(val[kind.y] - keep * model[kind.y], 0.0f);
            if (kind.z >= 0) carried += cw.y * fmax(val[kind.z] - keep * model[kind.z], 0.0f);
            if (kind.w >= 0) carried += cw.z * fmax(val[kind.w] - keep * model[kind.w], 0.0f);
            val[m] = (trend ? (1.0f - tr) * model[m] : model[m]) + carried;
        }
    }
    float3 res[MAX_T];
    int row_of[MAX_T];
    for (int t = 0; t < n_tex; ++t) {
        int4 tv = t_vert[t];
        float4 tw = t_wt[t];
        int ids[3] = {tv.x, tv.y, tv.z};
        float wv[3] = {tw.x, tw.y, tw.z};
        float3 c[3];
        float vv[3];
        float4 td = t_dir[t];
        float vp = vis_i[(int)td.w];
        float3 plain = (float3)(0.0f);
        for (int v = 0; v < 3; ++v) {
            int m = ids[v];
            c[v] = m >= 0 ? val[m] : (float3)(0.0f);
            vv[v] = m >= 0 ? vis_i[(int)mv_dir[m].w] : 1.0f;
            plain += wv[v] * c[v];
        }
        float3 r = plain;
        if (use_vis) {
            float vmin = fmin(vv[0], fmin(vv[1], vv[2]));
            float vmax = fmax(vv[0], fmax(vv[1], vv[2]));
            float spread = vmax - vmin;
            if (spread > 0.0f) {
                float sp = fmax(spread, 1e-6f);
                float tl = clamp((vp - vmin) / sp, 0.0f, 1.0f);
                float3 cl = (float3)(0.0f), cs = (float3)(0.0f);
                float wl = 0.0f, ws = 0.0f;
                for (int v = 0; v < 3; ++v) {
                    float lit = clamp((vv[v] - vmin) / sp, 0.0f, 1.0f);
                    cl += wv[v] * lit * c[v];
                    wl += wv[v] * lit;
                    cs += wv[v] * (1.0f - lit) * c[v];
                    ws += wv[v] * (1.0f - lit);
                }
                cl /= fmax(wl, 1e-12f);
                cs /= fmax(ws, 1e-12f);
                r = (1.0f - spread) * r + spread * (tl * cl + (1.0f - tl) * cs);
            }
        }
        if (trend) {
            float3 l = td.xyz;
            r += tr * (alb * fmax(dot(n, l), 0.0f) + spc * lobe_at(n, l, spec_exp)) * vp;
        }
        res[t] = fmax(r, 0.0f);
        row_of[t] = tv.w;
    }
    float b = blend[p];
    if (use_spline && b < 1.0f) {
        float3 acc[MAX_T];
        for (int t = 0; t < n_tex; ++t)
            acc[t] = (float3)(0.0f);
        __global const uchar *c = codes + (size_t)p * 3;
        size_t stride = (size_t)n_pix * 3;
        for (int k = 0; k < n_samples; ++k) {
            float3 q = (float3)(c[0], c[1], c[2]);
            for (int t = 0; t < n_tex; ++t)
                if (row_of[t] >= 0)
                    acc[t] += spline_w[row_of[t] * n_samples + k] * q;
            c += stride;
        }
        float3 s = vload3(p, scale);
        for (int t = 0; t < n_tex; ++t) {
            if (row_of[t] < 0)
                continue;
            float3 a = fmax(acc[t] * (1.0f / 255.0f), 0.0f);
            float3 spl = a * a * sqrt(a) * s;  /* a ** (1 / SPLINE_GAMMA), SPLINE_GAMMA = 0.4 */
            int4 cn = t_corner[t];
            __global const uchar *c0 = codes + ((size_t)cn.x * n_pix + p) * 3;
            __global const uchar *c1 = codes + ((size_t)cn.y * n_pix + p) * 3;
            __global const uchar *c2 = codes + ((size_t)cn.z * n_pix + p) * 3;
            float3 cap = (float3)(fmax(decode[c0[0]], fmax(decode[c1[0]], decode[c2[0]])),
                                  fmax(decode[c0[1]], fmax(decode[c1[1]], decode[c2[1]])),
                                  fmax(decode[c0[2]], fmax(decode[c1[2]], decode[c2[2]]))) * s;
            spl = fmin(spl, cap);
            res[t] = fmax(b * res[t] + (1.0f - b) * spl, 0.0f);
        }
    }
    for (int t = 0; t < n_tex; ++t) {
        size_t o = ((size_t)slots[t] * 3) * n_pix + p;
        /* halves below the normal range flushed (the relighting kernels read them as zero) */
        float3 v = res[t];
        v = select(v, (float3)(0.0f), isless(v, (float3)(0x1p-14f)));
        vstore_half_rte(v.x, o, rows);
        vstore_half_rte(v.y, o + n_pix, rows);
        vstore_half_rte(v.z, o + 2 * (size_t)n_pix, rows);
    }
}
