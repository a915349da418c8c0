"""Every OpenCL kernel against its NumPy twin (NumPy is the reference)."""

import numpy as np
import pytest

from relight.errors import InputError
from relight.kernels.heightfield import NO_SURFACE, MarchSettings, grid_directions, horizon_numpy, visibility_numpy
from relight.kernels.sensor import SensorKernel, expose_numpy, frame_key, hash_normal
from relight.kernels.shading import LightShader, Surface, shade_lights_numpy

from .tolerances import (
    HORIZON_ABS,
    NOISE_STATS_ABS,
    SENSOR_CODE,
    SENSOR_MISMATCH_FRACTION,
    SHADE_ABS,
    SHADE_FLIP_FRACTION,
    SHADE_REL,
)


@pytest.fixture(scope="module")
def bumpy():
    """A 72x56 height field: a dome with a tall bump and a ridge that cast shadows, off-surface rim."""
    h, w = 56, 72
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    r2 = ((x - 36) / 30) ** 2 + ((y - 28) / 24) ** 2
    z = 20 * np.sqrt(np.clip(1 - r2, 0, None)) + 14 * np.exp(-((x - 30) ** 2 + (y - 24) ** 2) / 18.0)
    z += 6 * np.exp(-((y - 38) ** 2) / 4.0) * (np.abs(x - 40) < 15)
    inside = r2 < 1
    height = np.where(inside, z, NO_SURFACE).astype(np.float32)
    gy, gx = np.gradient(np.where(inside, z, 0.0))
    n = np.stack([-gx, gy, np.ones_like(gx)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    pix = np.flatnonzero(inside).astype(np.int32)
    rng = np.random.default_rng(0)
    p = pix.size
    return Surface(height=height, pix=pix, normal=n.reshape(-1, 3)[pix].astype(np.float32),
                   albedo=rng.uniform(0.2, 0.8, (p, 3)).astype(np.float32),
                   specular=rng.uniform(0.0, 1.0, p).astype(np.float32),
                   roughness=rng.uniform(0.1, 0.6, p).astype(np.float32),
                   wrap=rng.uniform(0.0, 0.4, (p, 3)).astype(np.float32))


def _compare(a, b):
    bad = (np.abs(a - b) > SHADE_ABS + SHADE_REL * np.abs(b)).any(axis=(0, 2))
    assert bad.mean() <= SHADE_FLIP_FRACTION, f"{bad.sum()} pixels differ, largest {np.abs(a - b).max()}"


def test_shade_lights_matches_numpy(bumpy):
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(24, 3))
    dirs[:4] = [[1, 0, 0.05], [-1, 0.2, 0.1], [0, 0, 1], [0.3, -0.2, -0.5]]  # grazing, frontal, behind
    power = rng.uniform(0, 3, (24, 3, 3))
    shader = LightShader(bumpy)
    out = shader.shade(dirs, power)
    ref = shade_lights_numpy(bumpy, dirs, power)
    assert out.shape == ref.shape == (3, bumpy.pix.size, 3) and out.dtype == np.float32
    _compare(out, ref)
    no_shadow = shader.shade(dirs, power, shadows=False)
    _compare(no_shadow, shade_lights_numpy(bumpy, dirs, power, shadows=False))
    # The test field casts real shadows: the shadow test changes many pixels.
    # shadowing changes a visible share (5 %) of pixels by more than rounding (definitional bound, not a tolerance)
    assert (np.abs(no_shadow - out).max(axis=(0, 2)) > 1e-3).mean() > 0.05


def test_shade_lights_from_a_turned_view_matches_numpy(bumpy):
    """A head turned by R is shaded in its own frame from view R^T z: the kernel's view
    argument against the twin's, and the default view is +Z."""
    rng = np.random.default_rng(4)
    dirs = rng.normal(size=(16, 3))
    power = rng.uniform(0, 3, (16, 2, 3))
    view = np.array([np.sin(np.radians(35)), -np.sin(np.radians(12)), 0.0])
    view[2] = np.sqrt(1 - view @ view)
    shader = LightShader(bumpy)
    turned = shader.shade(dirs, power, view=view)
    _compare(turned, shade_lights_numpy(bumpy, dirs, power, view=view))
    # the view moves the highlights: a visible share of pixels changes by more than rounding
    front = shader.shade(dirs, power)
    assert (np.abs(turned - front).max(axis=(0, 2)) > 1e-3).mean() > 0.05
    np.testing.assert_array_equal(front, shader.shade(dirs, power, view=(0, 0, 2)))
    with pytest.raises(InputError, match="view"):
        shader.shade(dirs, power, view=(0, 0, 0))


def test_shadows_exist_for_grazing_light(bumpy):
    px = (bumpy.pix % 72).astype(np.float32)
    py = (bumpy.pix // 72).astype(np.float32)
    pz = bumpy.height.ravel()[bumpy.pix]
    vis = visibility_numpy(bumpy.height, px, py, pz, np.array([1.0, 0.0, 0.15]), MarchSettings())
    # visibility neither all-open nor all-shut (definitional bound, not a tolerance)
    assert 0.05 < 1 - vis.mean() < 0.95


def test_horizon_table_matches_the_march(bumpy):
    n_dir = 16
    shader = LightShader(bumpy)
    shader.prepare_horizons(n_dir)
    table = shader.horizons()
    px = (bumpy.pix % 72).astype(np.float32)
    py = (bumpy.pix // 72).astype(np.float32)
    pz = bumpy.height.ravel()[bumpy.pix]
    for k, d in enumerate(grid_directions(n_dir)):
        np.testing.assert_allclose(table[:, k], horizon_numpy(bumpy.height, px, py, pz, d, MarchSettings()),
                                   atol=HORIZON_ABS)
    # Lights along the table's directions, at many elevations: reading the table equals marching.
    beta = 2 * np.pi * (np.arange(n_dir) + 0.5) / n_dir
    alpha = np.radians([20, 45, 70, 85, 89, 95, 110])
    a, b = np.meshgrid(alpha, beta, indexing="ij")
    dirs = np.stack([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)], axis=-1).reshape(-1, 3)
    col = np.tile(np.arange(n_dir), alpha.size)
    power = np.ones((dirs.shape[0], 1, 3))
    _compare(shader.shade(dirs, power, direction_index=col), shade_lights_numpy(bumpy, dirs, power))


def test_hash_normal_is_a_unit_normal():
    z = hash_normal(np.arange(400_000, dtype=np.uint32), frame_key(7, 3))
    assert abs(z.mean()) < NOISE_STATS_ABS and abs(z.std() - 1.0) < NOISE_STATS_ABS
    assert abs(np.corrcoef(z[:-1], z[1:])[0, 1]) < NOISE_STATS_ABS
    assert not np.array_equal(z[:100], hash_normal(np.arange(100, dtype=np.uint32), frame_key(7, 4)))


def test_sensor_matches_numpy():
    rng = np.random.default_rng(2)
    scene = rng.uniform(-0.05, 1.3, (90, 160, 3)).astype(np.float32)
    kern = SensorKernel((90, 160))
    gains = np.array([1.1, 0.95, 1.02])
    for key in (None, frame_key(1, 17)):
        out = kern.expose(scene, gains, 0.004, 3e-4, key)
        ref = expose_numpy(scene, gains, 0.004, 3e-4, key)
        assert out.dtype == np.uint8 and out.shape == scene.shape
        diff = np.abs(out.astype(int) - ref.astype(int))
        assert diff.max() <= SENSOR_CODE and (diff > 0).mean() <= SENSOR_MISMATCH_FRACTION
    # Saturation: values above full scale clip to 255, below zero to 0.
    assert kern.expose(np.full((90, 160, 3), 5.0, np.float32), np.ones(3), 0.0, 0.0, None).min() == 255
    assert kern.expose(np.full((90, 160, 3), -1.0, np.float32), np.ones(3), 0.0, 0.0, None).max() == 0


def test_pixel_major_halves_are_numpys_float16_bit_for_bit():
    """The maps kernel's own float -> half conversion (integer ops: no library call on a 16-wide
    vector) rounds as NumPy's float16 (IEEE round to nearest even) for every kind of value:
    ties, subnormal halves, the overflow edge, infinities and NaN; the padding texels are 0."""
    import pyopencl as cl

    from relight.kernels.runtime import aligned_zeros, build_program, get_runtime

    rng = np.random.default_rng(4)
    halves = rng.integers(0, 1 << 16, 4000, dtype=np.uint16).view(np.float16).astype(np.float32)
    ties = (np.arange(1, 2000, dtype=np.float32) * 2.0 ** -11 + 2.0 ** -12) * rng.choice([1, 64, 2.0 ** -14], 1999)
    special = np.array([0.0, -0.0, 65504.0, 65519.99, 65520.0, 1e9, -1e9, np.inf, -np.inf, np.nan, 2.0 ** -25,
                        2.0 ** -24, 3 * 2.0 ** -26, 5.96e-8, 6.1e-5, 1e-40], np.float32)
    vals = np.concatenate([halves, ties.astype(np.float32), special, rng.normal(0, 3, 3000).astype(np.float32)])
    n_pix, n_active = 64, 37  # 37 texels: the kernel writes 48 per pixel and channel, the last 11 zero
    vals = np.resize(vals, (-(-vals.size // (n_active * 3 * n_pix))) * n_active * 3 * n_pix)
    rt = get_runtime()
    kernel = cl.Kernel(build_program("reflectance", ()), "pixel_major_f16")
    mf = cl.mem_flags
    t_pad = 48
    for block in vals.reshape(-1, n_active, 3, n_pix):
        src = np.ascontiguousarray(block)
        out = aligned_zeros((n_pix, 3, t_pad), np.float16)
        b_in = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=src)
        b_out = cl.Buffer(rt.context, mf.WRITE_ONLY | mf.USE_HOST_PTR, hostbuf=out)
        kernel(rt.queue, (n_pix, t_pad // 16, 3), None, b_in, np.int32(n_active), np.int32(n_pix), np.int32(0),
               np.int32(t_pad), b_out)
        got, _ = cl.enqueue_map_buffer(rt.queue, b_out, cl.map_flags.READ, 0, out.shape, out.dtype)
        with np.errstate(over="ignore"):
            want = src.transpose(2, 1, 0).astype(np.float16)
        got = np.array(got)
        nan = np.isnan(want)
        assert np.array_equal(np.isnan(got[:, :, :n_active]), nan)
        np.testing.assert_array_equal(got[:, :, :n_active].view(np.uint16)[~nan], want.view(np.uint16)[~nan])
        assert not got[:, :, n_active:].view(np.uint16).any()
