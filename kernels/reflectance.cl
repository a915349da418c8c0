/* Reflectance maps from light samples (relight.kernels.maps; NumPy twin:
 * relight.pipeline.reflectance.visibility_maps / build_maps).
 *
 * soft_visibility: per (pixel, texel), whether the texel's direction clears the pixel's horizon
 *   (soft over VIS_SOFT of elevation), from a horizon table over image-plane directions.
 * box3: the paper's 3x3 box filter of those maps (wrapping in azimuth, clamped at the poles).
 * build_maps: per pixel, every active texel interpolated from its triangle's vertices with
 *   visibility-aware blending and light adaptation (paper Eq. 1-3); written pixel-major
 *   (P, 3, T padded to 16), the layout relighting reads fastest.
 */
#include "common.h"

#define MIN_COS 0.1f

__kernel void soft_visibility(
    __global const float *horizon, int n_az,          /* (P, n_az) horizon elevations (radians) */
    __global const float4 *texel_az, int n_tex,       /* (T,) x, y = azimuth columns, z = blend, w = elevation */
    float inv_soft, int p0, int n_pix,                /* pixel range [p0, p0 + n_pix) */
    __global float *out)                              /* (n_pix, T) */
{
    int t = get_global_id(0); /* texels fastest: neighbouring work items share a pixel's row */
    int i = get_global_id(1);
    if (i >= n_pix || t >= n_tex)
        return;
    float4 ta = texel_az[t];
    float v = 1.0f;
    if (ta.w < 4.0f) { /* elevation 4 marks "straight at the camera": always visible */
        __global const float *hz = horizon + (size_t)(p0 + i) * n_az;
        v = clamp(0.5f + (ta.w - mix(hz[(int)ta.x], hz[(int)ta.y], ta.z)) * inv_soft, 0.0f, 1.0f);
    }
    out[(size_t)i * n_tex + t] = v;
}

__kernel void box3(__global const float *in, int w, int h, int n_pix, __global float *out)
{
    int x = get_global_id(0); /* texel column fastest */
    int y = get_global_id(1);
    int i = get_global_id(2);
    if (i >= n_pix || x >= w || y >= h)
        return;
    __global const float *m = in + (size_t)i * w * h;
    int xl = x == 0 ? w - 1 : x - 1, xr = x == w - 1 ? 0 : x + 1;
    float acc = 0.0f;
    for (int dy = -1; dy <= 1; ++dy) {
        __global const float *row = m + clamp(y + dy, 0, h - 1) * w;
        acc += row[xl] + row[x] + row[xr];
    }
    out[(size_t)i * w * h + y * w + x] = acc * (1.0f / 9.0f);
}

/* Light-adapted interpolation with vertex weights wv * use (paper Eq. 1-3). */
inline float3 adapt(const float3 *c, const float *wv, const float *dv, float dp, const float *use, int adaptation)
{
    float w[3], wsum = 0.0f;
    for (int v = 0; v < 3; ++v) {
        w[v] = wv[v] * use[v];
        wsum += w[v];
    }
    float inv = 1.0f / fmax(wsum, 1e-12f);
    float3 plain = (float3)(0.0f);
    for (int v = 0; v < 3; ++v) {
        w[v] *= inv;
        plain += w[v] * c[v];
    }
    if (!adaptation)
        return plain;
    int n_use = 0, n_lit = 0;
    float w_lit = 0.0f, w_ind = 0.0f;
    float3 c_ind = (float3)(0.0f);
    int lit[3];
    for (int v = 0; v < 3; ++v) {
        int inc = w[v] > 0.0f;
        lit[v] = inc && dv[v] > MIN_COS;
        n_use += inc;
        n_lit += lit[v];
        if (lit[v])
            w_lit += w[v];
        else if (inc) {
            w_ind += w[v];
            c_ind += w[v] * c[v];
        }
    }
    if (n_lit == 0)
        return plain;
    float dps = fmax(dp, 0.0f);
    if (n_lit == n_use) {
        float3 acc = (float3)(0.0f);
        for (int v = 0; v < 3; ++v)
            if (lit[v])
                acc += (w[v] / fmax(dv[v], MIN_COS)) * c[v];
        return acc * dps;
    }
    /* c_ind above is already the weighted sum w_ind * (normalised indirect estimate). */
    float3 acc = (float3)(0.0f);
    for (int v = 0; v < 3; ++v)
        if (lit[v])
            acc += (w[v] / fmax(dv[v], MIN_COS)) * (c[v] - c_ind);
    float3 c_dir = acc * dps / fmax(w_lit, 1e-12f) + c_ind;
    return w_lit * c_dir + c_ind;
}

__kernel void build_maps(
    __global const float *samples, int n_samples, int n_pix_all,   /* (K, P_all, 3) */
    __global const float4 *normal,                                 /* (P_all,) */
    __global const float4 *vertex_dir, __global const int *vertex_texel,
    __global const int4 *tex_vertices, __global const float4 *tex_weights,
    __global const float4 *tex_dir, __global const int *tex_index, int n_active,
    __global const float *vis, int n_tex, int use_vis, int adaptation,  /* (n_pix, T) smoothed */
    /* trend: out = interpolation - offset + (coef * max(n . l, 0) + spec * lobe(l)) * visibility
       (the shading model; lobe = max(n . h, 0)^spec_exp where n . l > 0, h the half vector of l and +Z) */
    __global const float4 *trend_offset, __global const float4 *trend_coef, __global const float4 *trend_spec,
    int spec_exp, int use_trend,
    int p0, int n_pix, int t_pad,
#ifdef OUT_HALF
    __global half *out)                                            /* (P_all, 3, t_pad): pixel-major */
#else
    __global float *out)                                           /* (P_all, 3, t_pad): pixel-major */
#endif
{
    int i = get_global_id(0);
    if (i >= n_pix)
        return;
    int p = p0 + i;
    float3 n = normal[p].xyz;
    __global const float *pv = vis + (size_t)i * n_tex;
    for (int a = 0; a < n_active; ++a) {
        int4 tv = tex_vertices[a];
        float4 tw = tex_weights[a];
        int ids[3] = {tv.x, tv.y, tv.z};
        float wv[3] = {tw.x, tw.y, tw.z};
        float3 c[3];
        float dv[3], vv[3];
        for (int v = 0; v < 3; ++v) {
            int id = ids[v];
            if (id < n_samples) {
                __global const float *s = samples + ((size_t)id * n_pix_all + p) * 3;
                c[v] = (float3)(s[0], s[1], s[2]);
            } else {
                c[v] = (float3)(0.0f);
            }
            dv[v] = adaptation ? dot(n, vertex_dir[id].xyz) : 1.0f;
            vv[v] = use_vis ? pv[vertex_texel[id]] : 1.0f;
        }
        float dp = adaptation ? dot(n, tex_dir[a].xyz) : 1.0f;
        float every[3] = {1.0f, 1.0f, 1.0f};
        float3 res = adapt(c, wv, dv, dp, every, adaptation);
        if (use_vis) {
            float vmin = fmin(vv[0], fmin(vv[1], vv[2]));
            float vmax = fmax(vv[0], fmax(vv[1], vv[2]));
            float spread = vmax - vmin;
            if (spread > 0.0f) {
                float is_lit[3], is_sh[3];
                for (int v = 0; v < 3; ++v) {
                    is_lit[v] = clamp((vv[v] - vmin) / fmax(spread, 1e-6f), 0.0f, 1.0f);
                    is_sh[v] = 1.0f - is_lit[v];
                }
                float vp = pv[tex_index[a]];
                float tl = clamp((vp - vmin) / fmax(spread, 1e-6f), 0.0f, 1.0f);
                float3 cl = adapt(c, wv, dv, dp, is_lit, adaptation);
                float3 cs = adapt(c, wv, dv, dp, is_sh, adaptation);
                res = (1.0f - spread) * res + spread * (tl * cl + (1.0f - tl) * cs);
            }
        }
        if (use_trend) {
            float3 l = tex_dir[a].xyz;
            float tv = use_vis ? pv[tex_index[a]] : 1.0f;
            float nl = dot(n, l);
            float3 h = l + (float3)(0.0f, 0.0f, 1.0f);
            float hn = length(h);
            float nh = hn > 1e-6f ? fmax(dot(n, h) / hn, 0.0f) : 0.0f;
            float lobe = nl > 0.0f ? ipow(nh, spec_exp) : 0.0f;
            res += (trend_coef[p].xyz * fmax(nl, 0.0f) + trend_spec[p].xyz * lobe) * tv - trend_offset[p].xyz;
        }
        res = fmax(res, 0.0f);
        size_t o = (size_t)p * 3 * t_pad + a;
#ifdef OUT_HALF
        /* Storage as half (what the bundle keeps): no float32 copy of maps that can be huge. */
        vstore_half_rte(res.x, o, out);
        vstore_half_rte(res.y, o + t_pad, out);
        vstore_half_rte(res.z, o + 2 * t_pad, out);
#else
        out[o] = res.x;
        out[o + t_pad] = res.y;
        out[o + 2 * t_pad] = res.z;
#endif
    }
    for (int a = n_active; a < t_pad; ++a) { /* zero padding */
        size_t o = (size_t)p * 3 * t_pad + a;
#ifdef OUT_HALF
        vstore_half(0.0f, o, out);
        vstore_half(0.0f, o + t_pad, out);
        vstore_half(0.0f, o + 2 * t_pad, out);
#else
        out[o] = 0.0f;
        out[o + t_pad] = 0.0f;
        out[o + 2 * t_pad] = 0.0f;
#endif
    }
}
