"""The thin-plate spline over light directions and the per-pixel blend with the shading model."""

import numpy as np
import pytest

from relight.directions import fibonacci_sphere
from relight.kernels.spline import SPLINE_GAMMA, spline_values, spline_weights
from relight.pipeline.shading_fit import model_maps
from relight.pipeline.stacking import leave_one_out, stacking_terms, stacking_weight
from relight.pipeline.triangulate import inside_hull, triangulate

from .lights import front_directions
from .tolerances import F32_CLOSE, F32_EXACT, F64_CLOSE, F64_SOLVE, SPLINE_GAIN


def test_weights_interpolate_the_samples_and_reproduce_linear_functions():
    dirs = front_directions(40, min_z=0.3)
    query = fibonacci_sphere(300)
    query = query[inside_hull(dirs, query)]
    w = spline_weights(dirs, np.concatenate([dirs, query]))
    assert w is not None and np.isfinite(w).all()
    np.testing.assert_allclose(w[:40], np.eye(40), atol=F64_SOLVE)  # passes through every sample
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=F64_CLOSE)
    f = 0.7 + dirs @ [0.2, -0.1, 0.3]  # a linear polynomial of the direction is reproduced exactly
    np.testing.assert_allclose(w[40:] @ f, 0.7 + query @ [0.2, -0.1, 0.3], atol=F64_CLOSE)


def test_values_in_the_power_domain():
    dirs = front_directions(30, seed=1, min_z=0.3)
    query = dirs[:5] * 0.9 + dirs[5:10] * 0.1
    query /= np.linalg.norm(query, axis=1, keepdims=True)
    w = spline_weights(dirs, query)
    # values whose SPLINE_GAMMA power is linear in the direction come back exactly
    lin = lambda d: 0.5 + d @ [0.1, 0.2, 0.1]  # noqa: E731
    samples = np.repeat(lin(dirs)[:, None, None], 3, axis=2) ** (1 / SPLINE_GAMMA)
    out = spline_values(samples.astype(np.float64), w)
    assert out.dtype == np.float64 and out.shape == (5, 1, 3)
    np.testing.assert_allclose(out[:, 0, 0], lin(query) ** (1 / SPLINE_GAMMA), rtol=F64_CLOSE)
    assert spline_values(samples.astype(np.float32), w).dtype == np.float32
    # a lone bright sample among black ones: overshoot below zero is clipped, nothing non-finite
    spike = np.zeros((30, 1, 3), np.float32)
    spike[3] = 1e4
    out = spline_values(spike, spline_weights(dirs, fibonacci_sphere(200)))
    assert np.isfinite(out).all() and (out >= 0).all()


@pytest.mark.parametrize("dirs", [
    np.eye(3),  # fewer than 4
    np.stack([np.cos(a := np.linspace(0, 3, 12)), np.sin(a), np.zeros(12)], axis=1),  # one great circle
])
def test_degenerate_directions_give_none(dirs):
    assert spline_weights(dirs, np.array([[0, 0, 1.0]])) is None


def test_leave_one_out_rows():
    dirs = front_directions(50, seed=2, min_z=0.3)
    idx, lin, spl = leave_one_out(dirs)
    assert 0 < len(idx) <= 50
    assert inside_hull(np.delete(dirs, idx[0], axis=0), dirs[idx[:1]])[0]
    for rows in (lin, spl):
        np.testing.assert_allclose(rows.sum(axis=1), 1.0, atol=F64_CLOSE)
        np.testing.assert_allclose(rows[np.arange(len(idx)), idx], 0.0)
    assert (lin >= 0).all() and ((lin > 0).sum(axis=1) <= 3).all()
    assert leave_one_out(dirs[:4]) is None


def test_stacking_picks_the_path_that_predicts_left_out_samples():
    dirs = front_directions(50, seed=3, min_z=0.3)
    loo = leave_one_out(dirs)
    n = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
    lambert = np.clip(dirs @ n, 0, None)
    smooth = (0.5 + dirs @ [0.3, -0.2, 0.1]) ** (1 / SPLINE_GAMMA)  # exact for the spline
    samples = np.stack([lambert, smooth], axis=1)[..., None].repeat(3, axis=2)  # (K, 2, 3)
    model = np.stack([lambert, np.zeros_like(lambert)], axis=1)[..., None].repeat(3, axis=2)
    trust = np.array([1.0, 0.0])
    num, den = stacking_terms(samples, model, trust, loo)
    w = stacking_weight(num, den, trust)
    assert w[0] == pytest.approx(1.0)  # the model explains pixel 0 exactly
    assert w[1] == pytest.approx(0.0, abs=F32_EXACT)  # the spline explains pixel 1 exactly
    # no evidence either way (both paths exact, den 0): the pixel keeps its trust
    assert stacking_weight(np.zeros(2), np.zeros(2), np.array([0.3, 0.8])).tolist() == [0.3, 0.8]
    # pooled over a window of neighbours on the image grid: one weight for the pair
    grid = np.zeros((3, 4), bool)
    grid[1, 1:3] = True
    pooled = stacking_weight(num, den, trust, grid, radius=1)
    assert pooled[0] == pooled[1] == pytest.approx((num.sum()) / den.sum())


def test_full_maps_blend_in_the_spline_only_where_it_predicts_better():
    dirs = front_directions(60, seed=4, min_z=0.3)
    tri = triangulate(dirs)
    n = np.tile([0.0, 0.0, 1.0], (2, 1))
    lambert = np.clip(dirs @ n[0], 0, None)
    shiny = (0.4 + dirs @ [0.4, 0.3, 0.0]).clip(0.05) ** (1 / SPLINE_GAMMA)  # no Lambert fit explains it
    samples = np.stack([lambert, shiny], axis=1)[..., None].repeat(3, axis=2).astype(np.float32)
    with_spline, mt = model_maps(samples, n, tri, None, 64, backend="numpy")
    without, mt2 = model_maps(samples, n, tri, None, 64, spline=False, backend="numpy")
    assert np.array_equal(mt.active, mt2.active)
    act = np.flatnonzero(mt.active)
    inside = inside_hull(dirs, mt.texel_dirs[act])
    # the Lambertian pixel keeps the model (a spline of a clipped cosine would round its kink)
    np.testing.assert_allclose(with_spline[0][:, :act.size], without[0][:, :act.size], atol=F32_CLOSE)
    # the other one follows the spline inside the hull, nearer the truth than barycentric
    truth = (0.4 + mt.texel_dirs[act][inside] @ [0.4, 0.3, 0.0]).clip(0.05) ** (1 / SPLINE_GAMMA)
    err = lambda m: np.abs(m[1, 0, :act.size][inside] - truth).mean()  # noqa: E731
    assert err(with_spline) < SPLINE_GAIN * err(without)
    assert np.isfinite(with_spline).all()


def test_exact_code_sums_are_exact_for_any_chunk_of_columns():
    """The capture's spline sums from the 8-bit codes: the same bits for any chunk of columns
    (any BLAS blocking, threads or vector width), and the exact sums of the rounded weights -
    checked against integer arithmetic."""
    from relight.kernels.spline import exact_code_sums, fixed_point_weights, spline_weights

    rng = np.random.default_rng(2)
    dirs = rng.normal(size=(180, 3))
    dirs[:, 2] = np.abs(dirs[:, 2])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    w = spline_weights(dirs, rng.normal(size=(40, 3)))
    wf = fixed_point_weights(w)
    assert np.abs(wf - w).max() <= 2.0 ** -30  # far below float32's resolution of the sums
    codes = rng.integers(0, 256, (180, 999)).astype(np.uint8)
    whole = exact_code_sums(codes, wf)
    for cols in (np.arange(3, 999, 7), np.arange(500, 530), np.array([998])):
        np.testing.assert_array_equal(exact_code_sums(codes[:, cols], wf), whole[:, cols])
    # the grid of the rounded weights: whole numbers of 2^-s; the products summed as integers
    s = next(b for b in range(20, 80) if np.all(np.ldexp(wf, b) == np.rint(np.ldexp(wf, b))))
    ints = np.rint(np.ldexp(wf, s)).astype(np.int64) @ codes.astype(np.int64)
    np.testing.assert_array_equal(np.ldexp(whole, s), ints.astype(np.float64))
