"""Numerical stability of the reflectance-map methods: stiff cases against float64 references.

Every case is a small synthetic problem (a 16x13 head of about 120 pixels: a bump on a
slope, so some pixels have hard cast shadows; 3 to 60 sample directions; Lambert plus a
Blinn-Phong lobe; linear float32 samples) run through every variant of :data:`VARIANTS` the
way production runs it, and compared with the same computation in float64.

The production side and the references: :mod:`relight.bench.stability_reference`; the
cases and the synthetic head: :mod:`relight.bench.stability_cases`. Renders (cases
``sun_1e5`` and ``exposure_extremes``): a tiny bundle is built per variant by
:func:`~relight.pipeline.capture.finish` from a hand-made ``Prepared`` (given mask:
photometric stereo geometry on the synthetic images), written with
:func:`~relight.pipeline.bundle_write.write_bundle` and loaded back (:class:`BundleCache`).
``max_rel_error`` is the exact path's (``exact=True``: the full sum in float32); the default
compact path is a rank-k approximation chosen to meet a 1 % tolerance, so its error is a
modelling error: it is listed in ``detail`` and counts towards ``finite``, not towards
``max_rel_error``.

Error measure of one output: ``max |production - reference| / max(max |reference|, TINY)``
over every pixel, channel and stored texel (over the head's pixels for renders), computed in
float64; a non-finite production value makes it ``inf``. A row's ``max_rel_error`` is the
largest over the case's outputs (NaN when none could be compared, or a reference failed).

Use: ``rows = run_stability()`` (about 30 s on 2 cores), ``print(table(rows))``.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from relight.errors import InputError
from relight.pipeline import shading_fit
from relight.pipeline.triangulate import DEFAULT_MAP_SIZE

from .stability_cases import CASES, Head, make_head
from .stability_reference import (
    VARIANTS,
    MapProblem,
    RenderProblem,
    builder_maps,
    production_maps,
    relative_error,
    render_production,
    render_reference,
)

#: Expected bound of the baseline case's error: float16 storage rounds to 2^-11 (4.9e-4)
#: relative, the OpenCL kernel adds at most 1e-4 (float32 and a fast arctangent in visibility).
BASELINE_MAX_REL = 1e-3
#: Expected bound of the exact render path against its float64 reference: float32 sums of a
#: few hundred float16 texels times float32 light (observed ~1e-7).
RENDER_MAX_REL = 1e-5

#: Bound of a map's largest value over its pixel's brightest sample (``max_gain``): the shading
#: model beyond the samples is at most albedo + spec, albedo alone at most the brightest sample
#: over the least cosine a fit uses (``MODEL_MIN_COS``), the lobe's weight at most it over
#: ``MODEL_LOBE_SEEN``; interpolation and the spline stay within the samples. (Before the lobe
#: had to be seen, ``unseen_lobe`` reached 8e3 and ``grazing`` 23.)
MAX_MAP_GAIN = 1.0 / shading_fit.MODEL_MIN_COS + 1.0 / shading_fit.MODEL_LOBE_SEEN


class BundleCache:
    """Per variant, one tiny bundle of the baseline scene (built on first use, files in a temp folder)."""

    def __init__(self, head: Head, map_size, folder: Path):
        self.head, self.map_size, self.folder = head, tuple(map_size), Path(folder)
        self.bundles: dict[str, object] = {}

    def get(self, variant: str):
        if variant not in self.bundles:
            self.bundles[variant] = self._build(variant)
        return self.bundles[variant]

    def _build(self, variant: str):
        from relight.kernels.bundle import load_bundle
        from relight.pipeline.bundle_arrays import finish
        from relight.pipeline.bundle_write import write_bundle
        from relight.pipeline.capture_progress import Progress
        from relight.pipeline.capture_types import CaptureOptions, Prepared

        head = self.head
        base = head.baseline()
        k, (h, w) = len(base.dirs), head.mask.shape
        pix = np.flatnonzero(head.mask)
        images = np.zeros((k, h * w, 3), dtype=np.float32)
        images[:, pix] = base.samples
        ambient = np.zeros((h, w, 3), dtype=np.float32)
        ambient.reshape(-1, 3)[pix] = 0.05 * head.albedo
        prep = Prepared(images=images.reshape(k, h, w, 3), dirs=base.dirs, clipped=np.zeros((k, h, w), dtype=bool),
                        ambient=ambient, background=np.zeros((h, w, 3), dtype=np.uint8), origin=(0, 0),
                        frame_size=(w, h), face_local=None, mask=head.mask.copy(), meta={"kind": "stability"})
        opts = CaptureOptions(**VARIANTS[variant], map_size=self.map_size)
        arrays, meta, _, _ = finish(prep, opts, Progress(False), {})
        path = self.folder / f"{variant.replace(' ', '_')}.bundle"
        write_bundle(path, meta, arrays)
        return load_bundle(path)


def _produce(prob, variant: str, map_size, bundles: BundleCache | None, clock: list[float]):
    """Production outputs of one problem: ({name: array}, callable giving the reference in the
    same layout); the first output is the one ``max_rel_error`` measures. The production's wall
    time is added to ``clock[0]``, also when it raises."""
    if isinstance(prob, RenderProblem):
        if bundles is None:
            raise ValueError("render problems need a BundleCache")
        bundle = bundles.get(variant)  # built once per variant: not timed
        t0 = time.perf_counter()
        try:
            frames, relighter = render_production(prob, bundle)
        finally:
            clock[0] += time.perf_counter() - t0
        m = bundle.mask
        return {name: f[m] for name, f in frames.items()}, lambda: render_reference(prob, relighter)[m]
    tri, seconds = prob.triangulation(map_size)
    clock[0] += seconds
    if isinstance(tri, InputError):
        raise tri
    t0 = time.perf_counter()
    try:
        maps = production_maps(variant, prob, tri)
    finally:
        clock[0] += time.perf_counter() - t0
    wide, scale = builder_maps(variant, prob, tri, half=False)  # before float16 storage: the arithmetic alone
    wide = wide.astype(np.float64) * scale

    def reference():
        ref = prob.reference(variant, tri)
        out = np.zeros(maps.shape, dtype=np.float64)  # production's layout: zero padded texels
        out[:, :, :ref.shape[2]] = ref
        return out

    return {"maps": maps, "float32": wide}, reference


def map_gain(maps: np.ndarray, samples: np.ndarray) -> float:
    """The largest map value over its pixel's brightest sample (pixels with a positive sample):
    how far the maps go beyond what was measured (extrapolation, adaptation, a fitted lobe)."""
    top = np.asarray(samples, dtype=np.float64).max(axis=(0, 2))  # (P,)
    lit = top > 0
    if not lit.any():
        return 0.0
    peak = np.asarray(maps, dtype=np.float64).max(axis=(1, 2))[lit]
    return float((peak / top[lit]).max())


def evaluate(case: str, description: str, problems: list, variant: str, *, map_size=DEFAULT_MAP_SIZE,
             bundles: BundleCache | None = None) -> dict:
    """One row: the problems of a case through one variant, production against reference.

    Keys: case, description, variant, max_rel_error (float; NaN if nothing could be compared),
    finite (every production output finite), max_gain (the maps' largest value over their pixel's
    brightest sample, :func:`map_gain`; NaN for render-only cases), error (None, or ``"label: Type: message"`` of
    every production exception, joined by "; "), ok (every output finite and compared with a
    finite error, and every exception an :class:`InputError`: invalid input refused with a
    message - a handled case), seconds (wall time of the
    production path: the triangulation, made once per problem for all variants, is counted in
    each row; a render case's bundle is built once per variant and not counted), detail (the
    error of each output, warnings the production path raised, any reference failure).
    Nothing is raised: exceptions and warnings are recorded whatever the warning filters are.
    """
    errs, details, failures, gains = [], [], [], []
    finite, ok, clock = True, True, [0.0]
    for prob in problems:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                outputs, reference = _produce(prob, variant, map_size, bundles, clock)
            except Exception as exc:  # recorded, never raised: the report must list every crash
                ok &= isinstance(exc, InputError)
                failures.append(f"{prob.label}: {type(exc).__name__}: {exc}")
                continue
        finite &= all(bool(np.isfinite(o).all()) for o in outputs.values())
        if isinstance(prob, MapProblem):
            gains.append(map_gain(outputs["maps"], prob.samples))
        note = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
        note = f" (warned: {'; '.join(note)})" if note else ""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a reference of a non-finite input may warn
                ref = reference()
            per = {name: relative_error(o, ref) for name, o in outputs.items()}
        except Exception as exc:  # the reference cannot be computed (e.g. a non-finite input)
            errs.append(float("nan"))
            details.append(f"{prob.label}: reference failed ({type(exc).__name__}: {exc}){note}")
            continue
        errs.append(next(iter(per.values())))
        details.append(f"{prob.label}: " + ", ".join(f"{k} {v:.2g}" for k, v in per.items()) + note)
    max_err = float("nan")
    if errs and not np.isnan(errs).any():
        max_err = float(max(errs))
    ok = ok and finite and bool(np.isfinite(errs).all())
    return {"case": case, "description": description, "variant": variant, "max_rel_error": max_err,
            "finite": bool(finite), "error": "; ".join(failures) or None, "ok": bool(ok),
            "max_gain": max(gains) if gains else float("nan"),
            "seconds": round(clock[0], 4), "detail": "; ".join(details + failures)}


def run_stability(variants=None, *, map_size=DEFAULT_MAP_SIZE, cases=None) -> list[dict]:
    """Every case of :data:`CASES` (or the named ``cases``) through every variant of
    :data:`VARIANTS` (or the named ``variants``): one row per (case, variant), cases in order.

    See :func:`evaluate` for a row's keys and the module docstring for the references and the
    error measure (``max |production - reference| / max(max |reference|, TINY)``).
    """
    from threadpoolctl import threadpool_limits

    names = list(VARIANTS) if variants is None else list(variants)
    for v in names:
        if v not in VARIANTS:
            raise InputError(f"unknown variant {v!r}; choose from: {', '.join(VARIANTS)}")
    chosen = list(CASES) if cases is None else list(cases)
    for c in chosen:
        if c not in CASES:
            raise InputError(f"unknown case {c!r}; choose from: {', '.join(CASES)}")
    rows = []
    # Problems of a few hundred pixels gain nothing from BLAS threads, and on 2 cores they
    # fight PoCL's workers (measured: an eigh of 1024^2 took 10 s instead of 0.6 s).
    with threadpool_limits(limits=1, user_api="blas"), tempfile.TemporaryDirectory(prefix="relight-stab-") as tmp:
        head = make_head()
        bundles = BundleCache(head, map_size, Path(tmp))
        for name in chosen:
            case = CASES[name]
            problems = case.build(head)
            for v in names:
                rows.append(evaluate(case.name, case.description, problems, v, map_size=map_size, bundles=bundles))
        bundles.bundles.clear()  # release the memory maps before the folder goes
    return rows


def table(rows: list[dict]) -> str:
    """The rows as a plain-text table (case, variant, max relative error, finite, error)."""
    head = f"{'case':20s} {'variant':18s} {'max rel err':>11s} {'gain':>8s} {'finite':>6s} {'s':>6s}  error"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['case']:20s} {r['variant']:18s} {r['max_rel_error']:11.2e} {r['max_gain']:8.3g} "
                     f"{'yes' if r['finite'] else 'no':>6s} {r['seconds']:6.2f}  {r['error'] or ''}")
    return "\n".join(lines)
