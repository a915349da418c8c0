"""The numerical stability suite: every stiff case through every method, against float64."""

import math

import numpy as np
import pytest

from relight.pipeline.stability import (
    BASELINE_MAX_REL,
    CASES,
    RENDER_MAX_REL,
    VARIANTS,
    MapProblem,
    evaluate,
    make_head,
    run_stability,
)

#: Production defects the suite finds and that are not fixed yet: a case listed here is expected
#: to fail the finiteness test (strictly: fixing it makes the test say so). Empty: the float16
#: overflow it found (samples above 65504 -> inf maps) is fixed by ``sample_scale``.
KNOWN_NON_FINITE: dict[str, str] = {}
#: Cases whose rows measure renders (the exact path) rather than maps.
RENDER_CASES = ("sun_1e5",)


@pytest.fixture(scope="module")
def rows():
    return run_stability()


def _rows(rows, case):
    return [r for r in rows if r["case"] == case]


def test_one_row_per_case_and_variant(rows):
    assert [(r["case"], r["variant"]) for r in rows] == [(c, v) for c in CASES for v in VARIANTS]
    for r in rows:
        assert {"case", "description", "variant", "max_rel_error", "finite", "error", "seconds"} <= set(r)
        assert isinstance(r["max_rel_error"], float) and isinstance(r["finite"], bool)
        assert r["error"] is None or isinstance(r["error"], str)
        assert r["seconds"] >= 0 and "\n" not in r["description"]


@pytest.mark.parametrize("case", [
    pytest.param(c, marks=pytest.mark.xfail(strict=True, reason=KNOWN_NON_FINITE[c])) if c in KNOWN_NON_FINITE
    else c for c in CASES])
def test_every_output_is_finite_and_every_failure_a_clear_input_error(rows, case):
    for r in _rows(rows, case):
        assert r["finite"], r
        assert r["ok"], r  # compared with a finite error; any exception an InputError


def test_baseline_matches_float64_to_float16_precision(rows):
    for r in _rows(rows, "float32_vs_float64"):
        assert r["error"] is None and r["max_rel_error"] <= BASELINE_MAX_REL, r


@pytest.mark.parametrize("case", [c for c in CASES if c not in KNOWN_NON_FINITE and c != "float32_vs_float64"])
def test_stiff_cases_are_as_accurate_as_the_baseline(rows, case):
    bound = RENDER_MAX_REL if case in RENDER_CASES else BASELINE_MAX_REL
    for r in _rows(rows, case):
        assert r["max_rel_error"] <= bound, r


def test_too_few_samples_for_a_fit_is_recorded_as_an_input_error(rows):
    row = next(r for r in _rows(rows, "degenerate_hull") if r["variant"] == "ptm")
    assert "InputError: ptm needs at least 6 light samples, got 3" in row["error"]
    assert row["ok"] and math.isfinite(row["max_rel_error"])  # the great circle itself was fitted


def test_unknown_names_are_refused():
    from relight.errors import InputError

    with pytest.raises(InputError, match="unknown variant"):
        run_stability(["fulll"])
    with pytest.raises(InputError, match="unknown case"):
        run_stability(cases=["nope"])


@pytest.fixture(scope="module")
def small_problem():
    """The baseline problem cut to 24 pixels (fast)."""
    base = make_head().baseline()
    n = 24
    return MapProblem("24 pixels", base.dirs, np.ascontiguousarray(base.samples[:, :n]), base.normals[:n],
                      base.horizon[:n])


def _planted(p: MapProblem, label: str, dirs=None, samples=None) -> MapProblem:
    return MapProblem(label, p.dirs if dirs is None else dirs, p.samples if samples is None else samples,
                      p.normals, p.horizon)


def test_the_planted_problems_are_healthy_unplanted(small_problem):
    for v in VARIANTS:
        r = evaluate("clean", "control", [small_problem], v)
        assert r["ok"] and r["max_rel_error"] <= BASELINE_MAX_REL, r


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_non_finite_sample_is_refused_not_passed_on(small_problem, value):
    samples = small_problem.samples.copy()
    samples[5, 7, 1] = value
    bad = _planted(small_problem, f"{value} sample", samples=samples)
    for v in VARIANTS:
        r = evaluate("planted", "a non-finite sample", [bad], v)
        assert r["finite"] and "InputError: light samples hold NaN or infinite values" in r["error"], r


def test_the_suite_flags_non_finite_and_wrong_output():
    from relight.pipeline.stability import relative_error

    ref = np.ones((4, 3, 8))
    bad = ref.copy()
    bad[1, 2, 3] = np.nan
    assert relative_error(bad, ref) == float("inf")
    off = ref.copy()
    off[0, 0, 0] = 1.01
    assert relative_error(off, ref) == pytest.approx(0.01) and relative_error(off, ref) > BASELINE_MAX_REL


def test_the_suite_records_a_refused_input_without_crashing(small_problem):
    dirs = small_problem.dirs.copy()
    dirs[3] = np.nan
    bad = _planted(small_problem, "NaN direction", dirs=dirs)
    for v in VARIANTS:
        r = evaluate("planted", "a NaN light direction", [bad], v)
        assert r["error"] == "NaN direction: InputError: light directions must be finite (K, 3) vectors", r
        assert r["ok"] and r["finite"] and math.isnan(r["max_rel_error"])
