"""Stage 5: triangulation and reflectance maps, the stiff cases, and the OpenCL twin."""

import numpy as np
import pytest

from relight.errors import InputError
from relight.kernels.heightfield import NO_SURFACE, horizon_table
from relight.kernels.interpolation import MIN_COS, compute_maps, visibility_at, visibility_maps
from relight.pipeline.triangulate import inside_hull, triangulate

from .lights import front_directions
from .tolerances import F32_CLOSE, F64_CLOSE, MAPS_TWIN_REL, TREND_EFFECT, VISIBILITY_EFFECT


def _check(tri):
    assert np.isfinite(tri.texel_weights).all()
    np.testing.assert_allclose(tri.texel_weights.sum(axis=1), 1.0, atol=F64_CLOSE)
    assert (tri.texel_weights >= 0).all()


def test_partition_of_unity_inside_the_hull_and_black_outside():
    dirs = front_directions(60)
    tri = triangulate(dirs)
    _check(tri)
    samples = np.ones((60, 5, 3), dtype=np.float32)
    maps = compute_maps(samples, np.tile([0, 0, 1.0], (5, 1)), tri, horizon=None, n_az=64, adaptation=False,
                        backend="numpy")
    texels = tri.texel_dirs[tri.active]
    inside = inside_hull(dirs, texels)
    active = maps[:, :, :texels.shape[0]]  # pixel-major, zero padded to 16
    np.testing.assert_allclose(active[:, :, inside], 1.0, atol=F32_CLOSE)
    assert (maps <= 1.0 + 1e-5).all() and (maps[:, :, texels.shape[0]:] == 0).all()
    # Far outside the captured hull (behind the head) the maps are black: not even stored.
    assert not tri.active[tri.texel_dirs[:, 2] < -0.7].any()


@pytest.mark.parametrize("case", ["duplicates", "slivers", "poles", "great_circle", "three"])
def test_stiff_triangulations_stay_finite(case):
    rng = np.random.default_rng(1)
    if case == "duplicates":  # the hand paused: identical and near-identical directions
        base = front_directions(40)
        dirs = np.concatenate([base, base[:10], base[:10] + 1e-7])
    elif case == "slivers":  # three nearly collinear directions among others
        base = front_directions(30)
        line = np.array([[np.sin(a), 0.001 * i, np.cos(a)] for i, a in enumerate(np.linspace(-0.5, 0.5, 12))])
        dirs = np.concatenate([base, line])
    elif case == "poles":
        dirs = np.concatenate([front_directions(30), [[0, 1, 1e-4], [1e-4, 0.99999, 0.001], [0, -1, 0.001]]])
    elif case == "great_circle":  # every light on one great circle: a degenerate hull
        a = rng.uniform(-1.4, 1.4, 40)
        dirs = np.stack([np.sin(a), np.zeros_like(a), np.cos(a)], axis=1)
    else:
        dirs = np.array([[0, 0, 1.0], [0.5, 0, 0.86], [0, 0.5, 0.86]])
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    tri = triangulate(dirs)
    _check(tri)
    k = len(dirs)
    samples = rng.uniform(0, 1, (k, 7, 3)).astype(np.float32)
    normals = rng.normal(size=(7, 3))
    normals[:, 2] = np.abs(normals[:, 2])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for backend in ("numpy", "opencl"):
        maps = compute_maps(samples, normals, tri, horizon=None, n_az=64, backend=backend)
        assert np.isfinite(maps).all() and (maps >= 0).all()
        # Light adaptation divides by cosines no smaller than MIN_COS: bounded.
        assert maps.max() <= samples.max() / MIN_COS + 1e-4


def test_grazing_normals_are_bounded():
    dirs = front_directions(50)
    tri = triangulate(dirs)
    normals = np.array([[1.0, 0, 0], [0, 1.0, 0], [0.999, 0, 0.0447]])  # perpendicular to the camera
    samples = np.ones((50, 3, 3), dtype=np.float32)
    maps = compute_maps(samples, normals, tri, horizon=None, n_az=64, backend="opencl")
    assert np.isfinite(maps).all() and maps.max() <= 1 / MIN_COS + 1e-4


def test_too_few_or_bad_directions():
    with pytest.raises(InputError, match="at least 3"):
        triangulate(np.array([[0, 0, 1.0], [0, 1.0, 0]]))
    with pytest.raises(InputError, match="finite"):
        triangulate(np.array([[0, 0, 1.0], [np.nan, 0, 1], [0, 1.0, 0]]))
    with pytest.raises(InputError, match="zero length"):
        triangulate(np.array([[0, 0, 1.0], [0, 0, 0], [0, 1.0, 0]]))


def test_opencl_maps_match_numpy_with_visibility_and_adaptation():
    rng = np.random.default_rng(4)
    h, w = 40, 48
    y, x = np.mgrid[0:h, 0:w]
    z = (15 * np.exp(-((x - 20) ** 2 + (y - 20) ** 2) / 60.0) + 0.1 * x).astype(np.float32)
    mask = np.ones((h, w), dtype=bool)
    pix = np.flatnonzero(mask)[::7].astype(np.int32)
    horizon = np.arctan(horizon_table(np.where(mask, z, NO_SURFACE).astype(np.float32), pix, 64))
    dirs = front_directions(45, seed=2)
    tri = triangulate(dirs)
    samples = rng.uniform(0.05, 1.0, (45, pix.size, 3)).astype(np.float32)
    normals = rng.normal(size=(pix.size, 3))
    normals[:, 2] = np.abs(normals[:, 2]) + 0.3
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for adapt in (False, True):
        a = compute_maps(samples, normals, tri, horizon=horizon, n_az=64, adaptation=adapt, backend="opencl")
        b = compute_maps(samples, normals, tri, horizon=horizon, n_az=64, adaptation=adapt, backend="numpy")
        assert np.abs(a - b).max() <= MAPS_TWIN_REL * np.abs(b).max()
    # Visibility matters here: without it the maps differ.
    c = compute_maps(samples, normals, tri, horizon=None, n_az=64, backend="opencl")
    assert np.abs(a - c).max() > VISIBILITY_EFFECT
    # The shading-model trend (offset off, (coef x cosine + spec x lobe) x texel visibility
    # back), with and without visibility: twin again, and it does change the maps; so does the lobe.
    trend = (rng.uniform(0.0, 0.3, (pix.size, 3)), rng.uniform(0.0, 1.0, (pix.size, 3)))
    spec = trend + (rng.uniform(0.0, 1.0, (pix.size, 3)),)
    for hz in (horizon, None):
        for tr in (trend, spec):
            a = compute_maps(samples, normals, tri, horizon=hz, n_az=64, adaptation=False, trend=tr, backend="opencl")
            b = compute_maps(samples, normals, tri, horizon=hz, n_az=64, adaptation=False, trend=tr, backend="numpy")
            assert np.abs(a - b).max() <= MAPS_TWIN_REL * np.abs(b).max()
        plain = compute_maps(samples, normals, tri, horizon=hz, n_az=64, adaptation=False, backend="numpy")
        lambert = compute_maps(samples, normals, tri, horizon=hz, n_az=64, adaptation=False, trend=trend,
                               backend="numpy")
        assert np.abs(lambert - plain).max() > TREND_EFFECT
        assert np.abs(b - lambert).max() > TREND_EFFECT


def test_opencl_visibility_at_texels_matches_numpy():
    h, w = 30, 36
    y, x = np.mgrid[0:h, 0:w]
    z = (12 * np.exp(-((x - 15) ** 2 + (y - 14) ** 2) / 40.0)).astype(np.float32)
    pix = np.arange(h * w, dtype=np.int32)[::5]
    horizon = np.arctan(horizon_table(z, pix, 64))
    cols = np.array([0, 5, 700, 1023, 2047, 1500, 5])
    a = visibility_at(horizon, 64, (64, 32), cols, backend="opencl")
    b = visibility_at(horizon, 64, (64, 32), cols, backend="numpy")
    np.testing.assert_allclose(b, visibility_maps(horizon, 64, (64, 32)).reshape(len(pix), -1)[:, cols])
    assert np.abs(a - b).max() <= MAPS_TWIN_REL
    assert b.min() < 0.5 < b.max()  # some texels are shadowed, some not
