/* A phone camera's sensor on linear scene values (relight.kernels.sensor):
 * exposure and white-balance gains, Poisson-Gaussian noise, clipping, sRGB encoding, 8 bits.
 *
 * Noise is counter-based (hash of element index and a per-frame key), so any frame can be
 * re-created on its own and the NumPy twin (relight.kernels.sensor.expose_numpy) draws the
 * same numbers. A normal deviate is the standardised sum of four 16-bit uniforms (variance
 * exact, tails cut at 3.46 sigma - plenty for sensor noise, and no log/cos library calls).
 */

inline uint lowbias32(uint x)
{
    x ^= x >> 16;
    x *= 0x7feb352dU;
    x ^= x >> 15;
    x *= 0x846ca68bU;
    x ^= x >> 16;
    return x;
}

#define SUM4_MEAN 131070.0f              /* 4 * 65535 / 2 */
#define SUM4_INV_STD (1.0f / 37837.23f)  /* 1 / sqrt(4 * (65536^2 - 1) / 12) */

inline float hash_normal(uint k, uint key)
{
    uint a = lowbias32((2u * k) ^ key);
    uint b = lowbias32((2u * k + 1u) ^ key);
    float s = (float)(a & 0xffffu) + (float)(a >> 16) + (float)(b & 0xffffu) + (float)(b >> 16);
    return (s - SUM4_MEAN) * SUM4_INV_STD;
}

__kernel void expose(
    __global const float *scene, int n,                /* (H * W * 3) linear scene values */
    float gain_r, float gain_g, float gain_b,          /* exposure x white balance per channel */
    float read_var, float shot_gain, uint key, int noisy,
    __global const uchar *lut, int lut_n,              /* sRGB code for linear i / lut_n */
    __global uchar *out)
{
    int k = get_global_id(0);
    if (k >= n)
        return;
    int c = k % 3;
    float g = c == 0 ? gain_r : (c == 1 ? gain_g : gain_b);
    float x = scene[k] * g;
    if (noisy)
        x += sqrt(read_var + shot_gain * fmax(x, 0.0f)) * hash_normal((uint)k, key);
    float idx = clamp(x * (float)lut_n + 0.5f, 0.0f, (float)lut_n);
    out[k] = lut[(int)idx];
}
