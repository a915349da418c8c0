import numpy as np
import pytest

from relight.colour import decode_srgb8, encode_srgb8, linear_to_srgb, luminance, srgb_to_linear

from .tolerances import F32_EXACT, F32_LOOSE, F32_ZERO, FAST_SRGB_MISMATCH, SRGB_ROUNDTRIP


def test_reference_values():
    # IEC 61966-2-1: the linear segment below 0.04045 and the mid-grey anchor.
    assert srgb_to_linear(np.array([0.0, 1.0]))[0] == 0.0
    assert srgb_to_linear(np.array([1.0]))[0] == pytest.approx(1.0)
    assert srgb_to_linear(np.array([0.04045]))[0] == pytest.approx(0.04045 / 12.92)
    assert linear_to_srgb(np.array([0.18]))[0] == pytest.approx(0.46135, abs=F32_LOOSE)


def test_round_trip_and_dtype():
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    y = srgb_to_linear(linear_to_srgb(x))
    assert y.dtype == np.float32
    np.testing.assert_allclose(y, x, atol=SRGB_ROUNDTRIP * 10)


def test_encode_lut_matches_formula_to_the_code():
    x = np.random.default_rng(0).uniform(-0.1, 1.1, size=(64, 64, 3)).astype(np.float32)
    exact = np.round(linear_to_srgb(x).astype(np.float64) * 255).astype(np.int32)
    fast = encode_srgb8(x).astype(np.int32)
    assert fast.shape == x.shape and fast.dtype == np.int32
    assert np.abs(fast - exact).max() <= 1
    assert (fast != exact).mean() < FAST_SRGB_MISMATCH


def test_decode_is_exact_per_code():
    codes = np.arange(256, dtype=np.uint8)
    np.testing.assert_allclose(decode_srgb8(codes), srgb_to_linear(codes / 255.0), atol=F32_ZERO)
    assert (encode_srgb8(decode_srgb8(codes)) == codes).all()


def test_luminance_of_white_is_one():
    assert luminance(np.ones(3)) == pytest.approx(1.0, abs=F32_EXACT)
