/* Shared helpers for relight's OpenCL kernels.
 *
 * Conventions: image arrays are row-major (row y, column x), pixel centres at integer
 * coordinates; camera space +X right, +Y up (image rows grow downward), +Z toward the camera.
 */
#ifndef RELIGHT_COMMON_H
#define RELIGHT_COMMON_H

#define PI_F 3.14159265358979323846f

/* Heights at or below this mark "no surface here": it never occludes. */
#define NO_SURFACE (-1.0e30f)

/* PoCL 3.0 turns normalize(), pown() and hypot() into slow library calls (measured ~7x
 * slower per light in synth_shade); these inline forms vectorise. */
inline float3 unit3(float3 v) { return v * rsqrt(fmax(dot(v, v), 1e-30f)); }
inline float pow5(float x) { float x2 = x * x; return x2 * x2 * x; }
inline float len2(float x, float y) { return sqrt(x * x + y * y); }

/* Bilinear height at (x, y) in pixels; NO_SURFACE outside the grid. */
inline float sample_height(__global const float *height, int w, int h, float x, float y)
{
    if (x < 0.0f || y < 0.0f || x > (float)(w - 1) || y > (float)(h - 1))
        return NO_SURFACE;
    int x0 = min((int)x, w - 2);
    int y0 = min((int)y, h - 2);
    float fx = x - (float)x0, fy = y - (float)y0;
    __global const float *r0 = height + (size_t)y0 * w + x0;
    __global const float *r1 = r0 + w;
    float a = mix(r0[0], r0[1], fx);
    float b = mix(r1[0], r1[1], fx);
    return mix(a, b, fy);
}

#endif
