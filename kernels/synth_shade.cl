/* Ground-truth shading of the synthetic studio's head (relight.kernels.shading).
 *
 * A head is a height field (pixels, +Z toward the camera). Each work item shades one pixel
 * under many directional lights: a skin BRDF (wrapped diffuse with a per-channel wrap for the
 * subsurface look, plus a GGX lobe with Schlick Fresnel) times a cast-shadow test along the
 * light ray. power[l, e] weights light l into output e, so several environments and
 * one-light images accumulate in one pass (in double precision).
 *
 * The camera looks along -Z (orthographic), so the view direction is +Z; a head turned by R is
 * shaded in its own frame with the lights and the view turned back (view = R^T z).
 *
 * Cast shadows (heightfield.h): lights tagged with a horizon-table column read their
 * visibility from the table (lights on a camera-axis grid share a few image-plane directions),
 * the others march their ray. NumPy twin: relight.kernels.shading.shade_lights_numpy.
 */
#include "common.h"
#include "heightfield.h"

#pragma OPENCL EXTENSION cl_khr_fp64 : enable

#ifndef MAX_OUT
#define MAX_OUT 16
#endif
#define SKIN_F0 0.028f

/* Reflected radiance per unit irradiance toward the unit direction v (the camera), already
   multiplied by the cosine (f * cos). */
inline float3 skin_brdf_cos(float3 n, float3 l, float3 v, float4 alb, float4 mat)
{
    float c = dot(n, l);
    float3 wrap = mat.yzw;
    float3 diffuse = alb.xyz * (1.0f / PI_F) * fmax((float3)(c) + wrap, 0.0f) / (1.0f + wrap);
    float spec = 0.0f;
    float nv = dot(n, v);
    if (c > 0.0f && nv > 0.0f && alb.w > 0.0f) {
        float3 hv = unit3(l + v);
        float nh = fmax(dot(n, hv), 0.0f);
        float vh = fmax(dot(v, hv), 0.0f);
        float a = mat.x * mat.x;
        float a2 = a * a;
        /* 1 + nh^2 (a2 - 1) cancels badly near the peak of a sharp lobe; |n x h|^2 = 1 - nh^2
           keeps float32 accurate there. */
        float3 nxh = cross(n, hv);
        float d = dot(nxh, nxh) + nh * nh * a2;
        float D = a2 / (PI_F * d * d);
        float k = 0.5f * a;
        float G = (c / (c * (1.0f - k) + k)) * (nv / (nv * (1.0f - k) + k));
        float F = SKIN_F0 + (1.0f - SKIN_F0) * pow5(1.0f - vh);
        spec = alb.w * D * G * F / (4.0f * nv);
    }
    return diffuse + (float3)(spec);
}

__kernel void shade_lights(
    __global const float *height, int w, int h,         /* (h, w) heights, pixels, +Z to camera */
    __global const float *tilemax, int tw, int th,      /* (th, tw) dilated tile maxima */
    __global const int *pix, int n_pix,                 /* (P,) flat indices of shaded pixels */
    __global const float4 *normal,                      /* (P,) unit normals, xyz */
    __global const float4 *albedo,                      /* (P,) diffuse albedo rgb, w = specular scale */
    __global const float4 *material,                    /* (P,) x = GGX roughness, yzw = wrap rgb */
    __global const float4 *lights, int n_lights,        /* (L,) unit directions toward the lights */
    __global const int *light_dir,                      /* (L,) horizon column, or -1: march */
    __global const float *horizons, int n_dir,          /* (P, n_dir) slopes from horizon() */
    __global const float4 *power, int n_out,            /* (L, E) radiance x solid angle, rgb */
    float start, float step, float growth, float bias, float hmax, int shadows,
    float4 view,                                        /* xyz: unit direction toward the camera */
    __global float4 *out)                               /* (E, P) rgb */
{
    int i = get_global_id(0);
    if (i >= n_pix)
        return;
    int p = pix[i];
    float x = (float)(p % w), y = (float)(p / w), z = height[p];
    float3 n = normal[i].xyz, v = view.xyz;
    float4 alb = albedo[i], mat = material[i];
    float wrap_max = fmax(mat.y, fmax(mat.z, mat.w));
    double4 acc[MAX_OUT];
    for (int e = 0; e < n_out; ++e)
        acc[e] = (double4)(0.0);
    for (int j = 0; j < n_lights; ++j) {
        float3 l = lights[j].xyz;
        if (dot(n, l) + wrap_max <= 0.0f)
            continue;
        if (shadows) {
            float s = len2(l.x, l.y);
            if (s >= 1e-6f) {
                float dz = l.z / s;
                int k = light_dir[j];
                int vis = k >= 0 ? dz >= horizons[(size_t)i * n_dir + k]
                                 : visible(height, w, h, tilemax, tw, th, x, y, z, l.x / s, -l.y / s, dz,
                                           start, step, growth, bias, hmax);
                if (!vis)
                    continue;
            }
        }
        float3 f = skin_brdf_cos(n, l, v, alb, mat);
        double4 fd = convert_double4((float4)(f, 0.0f));
        __global const float4 *pw = power + (size_t)j * n_out;
        for (int e = 0; e < n_out; ++e)
            acc[e] += fd * convert_double4(pw[e]);
    }
    for (int e = 0; e < n_out; ++e)
        out[(size_t)e * n_pix + i] = convert_float4(acc[e]);
}
