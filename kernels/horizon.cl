/* Horizon tables of a height field (relight.kernels.heightfield.HorizonTable). */
#include "common.h"
#include "heightfield.h"

/* Horizon slopes: out[i * n_dir + k] for pixel i and image-plane direction k. */
__kernel void horizon(
    __global const float *height, int w, int h,
    __global const float *tilemax, int tw, int th,
    __global const int *pix, int n_pix,
    __global const float2 *dirs, int n_dir,            /* unit image-plane directions (x right, y down) */
    float start, float step, float growth, float bias, float hmax,
    __global float *out)
{
    int i = get_global_id(0);
    if (i >= n_pix)
        return;
    int p = pix[i];
    float x = (float)(p % w), y = (float)(p / w), z = height[p];
    for (int k = 0; k < n_dir; ++k) {
        float2 d = dirs[k];
        out[(size_t)i * n_dir + k] = horizon_slope(height, w, h, tilemax, tw, th, x, y, z, d.x, d.y,
                                                   start, step, growth, bias, hmax);
    }
}

