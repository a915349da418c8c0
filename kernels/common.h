/* Shared helpers for relight's OpenCL kernels.
 *
 * Conventions: image arrays are row-major (row y, column x), pixel centres at integer
 * coordinates; camera space +X right, +Y up (image rows grow downward), +Z toward the camera.
 */
#ifndef RELIGHT_COMMON_H
#define RELIGHT_COMMON_H

#define PI_F 3.14159265358979323846f

/* PoCL 3.0 turns normalize(), pown() and hypot() into slow library calls (measured ~7x
 * slower per light in synth_shade); these inline forms vectorise. */
inline float3 unit3(float3 v) { return v * rsqrt(fmax(dot(v, v), 1e-30f)); }
inline float pow5(float x) { float x2 = x * x; return x2 * x2 * x; }
inline float len2(float x, float y) { return sqrt(x * x + y * y); }
/* x ** n for a whole n >= 0 by squaring (pow() is a slow library call in PoCL 3.0: it made
 * the specular lobe the cost of the maps kernels). */
inline float ipow(float x, int n)
{
    float r = 1.0f;
    while (n > 0) {
        if (n & 1)
            r *= x;
        x *= x;
        n >>= 1;
    }
    return r;
}

/* PoCL (3.x, the pyopencl wheel's) calls its builtins out of line - fmax, fmin, clamp, mix, dot,
 * select, min, length - and a call stops the vectoriser that runs a work-group's items as SIMD
 * lanes (POCL_VECTORIZER_REMARKS=1 shows it). Kernels that should vectorise use these scalar
 * forms instead (and no vector types: a float3 in the body stops it too). */
inline float mxf(float a, float b) { return a > b ? a : b; }
inline float mnf(float a, float b) { return a < b ? a : b; }
inline float clamp01(float x) { return mnf(mxf(x, 0.0f), 1.0f); }
inline float lerpf(float a, float b, float t) { return a + (b - a) * t; }

#endif
