"""The maps' recipe (a default bundle's content): storage codes, and the three makers of maps
from it - all texels on the device, a few texels on the device, a few texels in NumPy - agree."""

import dataclasses

import numpy as np
import pytest

from relight.errors import InputError
from relight.kernels import recipe as rcp
from relight.pipeline import recipe_write

from .tolerances import F32_CLOSE, HALF_REL

#: float16 storage of maps (relative), and the halves flushed to zero below HALF_TINY.
HALF_RTOL = 2e-3


def test_sample_codes_keep_relative_precision_and_never_exceed_the_scale():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (40, 500, 3)).astype(np.float32) ** 3 * rng.uniform(0.01, 3000, (1, 500, 3))
    x[3, 7, 1] = -0.01  # flash minus no-flash noise
    codes, scale = recipe_write.encode_samples(x)
    assert codes.dtype == np.uint8 and scale.dtype == np.float16
    assert (scale.astype(np.float32) >= x.max(axis=0)).all()  # rounded up
    y = rcp.decode_samples(codes, scale)
    assert y[3, 7, 1] == 0.0
    top = x.max(axis=0, keepdims=True)
    bright = x > 0.1 * top
    # 8-bit codes at gamma 2.5: a step is 2.5 / code relative, half a step of error at most.
    rel = np.abs(y - x)[bright] / x[bright]
    # half an 8-bit step at the gamma-2.5 code's steepest point, + float32 slack (definitional bound, not a tolerance)
    assert rel.max() < 0.5 * 2.5 / (255 * 0.1 ** 0.4) + 1e-3
    # half an 8-bit step of the peak, + 1 % for the scale's float16 rounding (definitional bound, not a tolerance)
    assert np.abs(y - x).max() <= 0.5 * 2.5 / 255 * top.max() * 1.01


def test_sample_codes_reject_what_float16_cannot_hold():
    with pytest.raises(InputError, match="float16"):
        recipe_write.encode_samples(np.full((2, 3, 3), 1e6, np.float32))
    with pytest.raises(InputError, match="NaN"):
        recipe_write.encode_samples(np.full((2, 3, 3), np.nan, np.float32))


def test_horizon_codes_round_trip_within_half_a_step():
    e = np.linspace(-np.pi / 2, np.pi / 2, 1001).astype(np.float32)
    back = rcp.decode_horizon(rcp.encode_horizon(e))
    # half an 8-bit step of the horizon's [0, pi] range (definitional bound, not a tolerance)
    assert np.abs(back - e).max() <= 0.5 * np.pi / 255 + 1e-6


@pytest.fixture(scope="module")
def recipe(small_bundle):
    r = small_bundle.recipe
    assert r is not None and r.horizon is not None
    return r


def _some_texels(bundle, n=8, seed=0):
    tex = np.asarray(bundle.map_texels)
    return np.sort(np.random.default_rng(seed).choice(tex, n, replace=False))


def test_texel_rows_kernel_matches_its_numpy_twin(small_bundle, recipe):
    from relight.kernels.recipe_cl import RecipeRows
    from relight.kernels.runtime import aligned_zeros
    from relight.numerics import HALF_TINY, read_halves

    texels = _some_texels(small_bundle, 11)  # more than one launch (8 per launch)
    rows = aligned_zeros((16, 3, recipe.n_pixels), np.float16)
    slots = np.arange(3, 14)
    RecipeRows(recipe, rows).make(texels, slots)
    ref = rcp.texel_rows(recipe, texels)
    np.testing.assert_allclose(read_halves(rows[slots]), ref, rtol=HALF_RTOL, atol=HALF_TINY)


def test_texel_rows_match_the_maps_made_for_all_texels(small_bundle, recipe):
    from relight.numerics import HALF_TINY

    maps = rcp.recipe_maps(recipe)  # what the capture made (float16)
    idx = np.searchsorted(np.asarray(small_bundle.map_texels), _some_texels(small_bundle, 6, seed=1))
    rows = rcp.texel_rows(recipe, np.asarray(small_bundle.map_texels)[idx])
    np.testing.assert_allclose(rows, maps[:, :, idx].transpose(2, 1, 0).astype(np.float32), rtol=HALF_RTOL,
                               atol=HALF_TINY)


def test_maps_of_a_subset_are_the_subset_of_the_maps(recipe):
    """Chunks of pixels (the capture's streamed transport, the live light's pixels) get exactly
    their rows of the whole - with a row per pixel or shared horizon rows (large heads)."""
    whole = rcp.recipe_maps(recipe)
    idx = np.arange(5, recipe.n_pixels, 7)
    np.testing.assert_array_equal(rcp.recipe_maps(recipe.subset(idx)), whole[idx])
    shared = dataclasses.replace(recipe, horizon=np.asarray(recipe.horizon)[::-1].copy(),
                                 horizon_index=np.arange(recipe.n_pixels)[::-1].astype(np.int32))
    np.testing.assert_array_equal(rcp.recipe_maps(shared.subset(idx)), whole[idx])


def test_texel_major_maps_are_the_maps_transposed_and_match_numpy(recipe):
    """The capture's transport reads the maps texel-major in float32 (the kernel's own layout,
    spline blended in on the device); the exact path pixel-major halves; the NumPy backend
    (interpolation and spline blend in NumPy) is the twin of both."""
    from relight.numerics import HALF_TINY

    sub = recipe.subset(np.arange(3, recipe.n_pixels, max(1, recipe.n_pixels // 300)))
    assert (np.asarray(sub.blend) < 1.0).any()  # the spline is blended in somewhere
    tm = rcp.recipe_maps(sub, texel_major=True)
    pm = rcp.recipe_maps(sub)
    assert tm.dtype == np.float32 and tm.shape == pm.shape[::-1]
    np.testing.assert_allclose(pm.astype(np.float32), tm.transpose(2, 1, 0), rtol=HALF_RTOL, atol=HALF_TINY)
    ref = rcp.recipe_maps(sub, backend="numpy", half=False)
    scale = float(ref.max())
    np.testing.assert_allclose(tm.transpose(2, 1, 0), ref, rtol=HALF_REL, atol=F32_CLOSE * scale)


def test_a_damaged_recipe_is_refused(small_bundle):
    from relight.kernels.recipe import recipe_from_arrays

    arrays = dict(small_bundle.arrays)
    arrays["horizon_index"] = np.full(small_bundle.n_pixels, 10 ** 6, np.int32)
    with pytest.raises(InputError, match="horizon"):
        recipe_from_arrays(arrays, small_bundle.meta, small_bundle.map_size)
    arrays = dict(small_bundle.arrays)
    arrays["samples_code"] = np.asarray(arrays["samples_code"])[:, :-1]
    with pytest.raises(InputError, match="recipe"):
        recipe_from_arrays(arrays, small_bundle.meta, small_bundle.map_size)


def test_the_default_bundle_is_small_and_keeps_no_maps(small_bundle):
    k = small_bundle.light_dirs.shape[0]
    per_pixel = small_bundle.path.stat().st_size / small_bundle.n_pixels
    assert not {"maps", "maps_rows", "samples"} & set(small_bundle.arrays)
    # 3 bytes per sample and pixel, the compact transport (at most 3 bytes per rank: 8 bits for
    # the first, 4 for the rest), the fits, the horizon and the crop's images: well under the
    # maps' 2 x 3 x T bytes.
    rank = small_bundle.arrays["transport_errors"].shape[0]
    assert per_pixel < 3 * k + 3 * rank + 200, per_pixel
