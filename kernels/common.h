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


#endif
