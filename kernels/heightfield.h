/* Height fields: bilinear heights, shadow-ray marching and horizon slopes
 * (relight.kernels.heightfield; NumPy twins there).
 *
 * A height field holds, per pixel, the surface's height toward the camera (pixels); the solid
 * lies behind it. A ray from (x, y, z) toward a light is marched over the image plane at
 * t = start, then t += max(step, growth * t); it is blocked iff some sample has
 * h(q) > z + t * dz + bias. horizon_slope() gives, for one image-plane direction, the largest
 * (h(q) - z - bias) / t over the same samples: every light along that direction is visible iff
 * its dz is at least that slope. Empty-space skipping uses dilated tile maxima and only skips
 * samples that cannot occlude, so both equal the plain march.
 */
#ifndef RELIGHT_HEIGHTFIELD_H
#define RELIGHT_HEIGHTFIELD_H

/* Heights at or below this mark "no surface here": it never occludes. */
#define NO_SURFACE (-1.0e30f)

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

#define TILE 8
#define NO_SLOPE (-1.0e30f)

inline float next_t(float t, float step, float growth) { return t + fmax(step, growth * t); }

inline int outside(float px, float py, int w, int h)
{
    return px < 0.0f || py < 0.0f || px > (float)(w - 1) || py > (float)(h - 1);
}

inline float tile_max(__global const float *tilemax, int tw, int th, float px, float py)
{
    int ti = min((int)(px * (1.0f / TILE)), tw - 1), tj = min((int)(py * (1.0f / TILE)), th - 1);
    return tilemax[tj * tw + ti];
}

/* 1 if the ray from (x, y, z) along image direction (dx, dy) rising dz per pixel is unblocked. */
inline int visible(__global const float *height, int w, int h,
                   __global const float *tilemax, int tw, int th,
                   float x, float y, float z, float dx, float dy, float dz,
                   float start, float step, float growth, float bias, float hmax)
{
    float tend = 2.0f * (float)(w + h);
    float t = start;
    while (t < tend) {
        float px = x + t * dx, py = y + t * dy, pz = z + t * dz;
        if (pz > hmax || outside(px, py, w, h))
            return 1;
        /* tilemax covers everything within TILE pixels of here: skip samples that cannot hit. */
        if (pz + fmin(0.0f, (float)TILE * dz) > tile_max(tilemax, tw, th, px, py) + bias) {
            float t1 = t + (float)TILE;
            while (t < t1)
                t = next_t(t, step, growth);
            continue;
        }
        if (sample_height(height, w, h, px, py) > pz + bias)
            return 0;
        t = next_t(t, step, growth);
    }
    return 1;
}

/* Largest (h(q) - z - bias) / t over the samples along image direction (dx, dy). */
inline float horizon_slope(__global const float *height, int w, int h,
                           __global const float *tilemax, int tw, int th,
                           float x, float y, float z, float dx, float dy,
                           float start, float step, float growth, float bias, float hmax)
{
    float m = NO_SLOPE;
    float tend = 2.0f * (float)(w + h);
    float t = start;
    while (t < tend) {
        float px = x + t * dx, py = y + t * dy;
        if (outside(px, py, w, h) || fmax(hmax - z - bias, 0.0f) / t <= m)
            break; /* nothing further can raise the slope */
        float num = tile_max(tilemax, tw, th, px, py) - z - bias;
        float t1 = t + (float)TILE;
        if (fmax(num / t, num / t1) <= m) {
            while (t < t1)
                t = next_t(t, step, growth);
            continue;
        }
        m = fmax(m, (sample_height(height, w, h, px, py) - z - bias) / t);
        t = next_t(t, step, growth);
    }
    return m;
}

#endif
