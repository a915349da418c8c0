"""The numerical stability suite: every stiff case through every method, against float64."""

import math

import numpy as np
import pytest

from relight.bench.stability import MapProblem, evaluate, make_head, run_stability
from relight.bench.stability_cases import CASES
from relight.bench.stability_reference import VARIANTS

from .tolerances import STABILITY_MAP_GAIN, STABILITY_MAPS_REL, STABILITY_RENDER_REL

#: Production defects the suite finds and that are not fixed yet: a case listed here is expected
#: to fail the finiteness test (strictly: fixing it makes the test say so). Empty: the float16
#: overflow it found (samples above 65504 -> inf maps) is fixed by ``sample_scale``.
KNOWN_NON_FINITE: dict[str, str] = {}
#: Cases whose rows measure renders (the exact path) rather than maps.
RENDER_CASES = ("sun_1e5",)


#: The errors a case must record for a variant, whole (the input refused with a clear message,
#: an InputError); every other row records none.
EXPECTED_ERRORS = {
    ("degenerate_hull", "ptm"): "3 lights: InputError: ptm needs at least 6 light samples, got 3; "
                                "4 lights: InputError: ptm needs at least 6 light samples, got 4",
    ("degenerate_hull", "hsh"): "3 lights: InputError: hsh needs at least 9 light samples, got 3; "
                                "4 lights: InputError: hsh needs at least 9 light samples, got 4",
    ("degenerate_hull", "hsh2"): "3 lights: InputError: hsh2 needs at least 4 light samples, got 3",
}


#: The cases that render through bundles (one tiny bundle per variant, built once per call of
#: run_stability): tested together so the bundles are built once.
BUNDLE_CASES = ("sun_1e5", "exposure_extremes")
#: Single cases left to `make test-slow` for their time (the rest keep every variant's checks in
#: `make test`).
SLOW_CASES = {"poles", "degenerate_hull", "duplicates", "saturated"}


def _case_params():
    groups = [(c,) for c in CASES if c not in BUNDLE_CASES] + [BUNDLE_CASES]
    # The bundle cases (~22 s: a bundle built per variant) and the longest single ones (~10 s
    # each) run in `make test-slow` (CI runs both).
    return [pytest.param(g, id="+".join(g), marks=[pytest.mark.xfail(strict=True, reason=KNOWN_NON_FINITE[c])
                                                   for c in g if c in KNOWN_NON_FINITE]
                         + ([pytest.mark.slow] if g == BUNDLE_CASES or set(g) & SLOW_CASES else []))
            for g in groups]


@pytest.mark.parametrize("cases", _case_params())
def test_each_case_through_every_variant_is_finite_and_as_accurate_as_the_baseline(cases):
    """Cases of the suite through every variant (a test per case - the bundle cases together -
    so pytest-xdist's workers share the cases out): one row per variant with its keys; every
    output finite; no error but the expected refusals (EXPECTED_ERRORS, whole); the error against
    float64 within STABILITY_MAPS_REL (a render case: the exact path's, STABILITY_RENDER_REL) -
    so compared, and finite; the maps never more than STABILITY_MAP_GAIN times their pixel's
    brightest sample. (The bench's own ``ok`` flag and bounds are not used: they are what is
    checked.)"""
    rows = run_stability(cases=list(cases))
    assert [(r["case"], r["variant"]) for r in rows] == [(c, v) for c in cases for v in VARIANTS]
    for r in rows:
        case = r["case"]
        bound = STABILITY_RENDER_REL if case in RENDER_CASES else STABILITY_MAPS_REL
        assert {"case", "description", "variant", "max_rel_error", "finite", "error", "seconds", "max_gain"} <= set(r)
        assert isinstance(r["max_rel_error"], float) and isinstance(r["finite"], bool)
        assert r["seconds"] >= 0 and "\n" not in r["description"]
        assert r["finite"], r
        assert r["error"] == EXPECTED_ERRORS.get((case, r["variant"])), r
        assert r["max_rel_error"] <= bound, r  # (NaN - nothing compared - fails too)
        if case not in RENDER_CASES:  # render-only cases have no maps of their own
            assert r["max_gain"] <= STABILITY_MAP_GAIN, r


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
        assert r["finite"] and r["error"] is None and r["max_rel_error"] <= STABILITY_MAPS_REL, r


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_non_finite_sample_is_refused_not_passed_on(small_problem, value):
    samples = small_problem.samples.copy()
    samples[5, 7, 1] = value
    bad = _planted(small_problem, f"{value} sample", samples=samples)
    for v in VARIANTS:
        r = evaluate("planted", "a non-finite sample", [bad], v)
        assert r["finite"] and "InputError: light samples hold NaN or infinite values" in r["error"], r


def test_the_suite_flags_non_finite_and_wrong_output():
    from relight.bench.stability_reference import relative_error

    ref = np.ones((4, 3, 8))
    bad = ref.copy()
    bad[1, 2, 3] = np.nan
    assert relative_error(bad, ref) == float("inf")
    off = ref.copy()
    off[0, 0, 0] = 1.01
    assert relative_error(off, ref) == pytest.approx(0.01) and relative_error(off, ref) > STABILITY_MAPS_REL


def test_the_suite_records_a_refused_input_without_crashing(small_problem):
    dirs = small_problem.dirs.copy()
    dirs[3] = np.nan
    bad = _planted(small_problem, "NaN direction", dirs=dirs)
    for v in VARIANTS:
        r = evaluate("planted", "a NaN light direction", [bad], v)
        assert r["error"] == "NaN direction: InputError: light directions must be finite (K, 3) vectors", r
        assert r["ok"] and r["finite"] and math.isnan(r["max_rel_error"])
