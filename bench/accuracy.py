"""``relight bench accuracy``: every method on the same captures, against the synthetic truth
and real held-out photos, with run time beside the error - one report.

Methods ("variants"): the paper's pipeline with what we added (``full``), its ablations
(without visibility, without light adaptation, without both, without the shading-model lights
beyond the captured hull), the paper's step 1 alone
(``barycentric``) and the baselines people use for sparse-light relighting (``ptm``, ``hsh`` of
order 3, ``hsh2`` of order 2, ``rbf``). Each scene's video is prepared once (flash separation,
registration, light directions) and every variant builds its maps from the same samples and the
same geometry; each becomes a bundle rendered by the same engine (the exact path), so what is
compared is the representation only.

Metrics, per variant x scene x environment, inside the face mask (bundle mask and truth mask):

* environments (the truth renders of ``relight synth``): PSNR (peak = the truth's maximum) and
  SSIM (Wang et al. 2004, scikit-image, on both images divided by that peak and clipped to
  [0, 1], averaged over the mask) after one least-squares exposure gain. ``in hull``
  environments keep only light well inside a frontal capture's hull; ``whole sphere`` ones
  light the head from everywhere (the paper limits its error maps to the hull).
* one light at a time (the paper's Fig. 14): the truth rendered for each of the 32x16 lat-long
  light directions and the variant's prediction (``Relighter.relight_light``), one exposure
  gain per variant and scene over all of them. Reported: RMS error relative to the truth's RMS,
  over the whole sphere of directions and over the captured hull only, each direction weighted
  by its solid angle (sin of the polar angle); and per pixel as heat maps (PNG).
* real data nobody here made: ``../shared/data/rti-dome`` - bundles from Dome's 49 lights
  predict Test's 20 held-out photos through ``relight_light`` (what ``render --light`` runs);
  PSNR / SSIM in sRGB inside the mask, no gain fitted.
* run time: capture seconds (the shared preparation + the variant's own maps), bundle MB and
  relight ms (default compact path, median of calls with the head turning).
* numerical stability: :mod:`relight.bench.stability`.

The parts, one job each: :mod:`~relight.bench.accuracy_synthetic` (the scenes against their
truth), :mod:`~relight.bench.accuracy_real` (the RTI dome and the real faces),
:mod:`~relight.bench.accuracy_bundles` (a bundle per variant from one preparation),
:mod:`~relight.bench.accuracy_metrics` (PSNR / SSIM) and :mod:`~relight.bench.accuracy_report`
(the summary, ``report.md``, the plot and the table); this module runs them and writes
``bench.json``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from .accuracy_bundles import build_variants
from .accuracy_real import (
    QUICK_FACES,
    evaluate_dome,
    evaluate_face,
    face_subjects,
)
from .accuracy_report import pareto_plot, report_markdown, summarise, summarise_faces
from .accuracy_synthetic import OLAT_GRID, QUICK_SCENES, SCENES, environments, evaluate_scene, slug, synthesize_scene
from .variants import VARIANTS

#: ``--quick`` builds these variants for its one subject (the others cost ~20 s each).
QUICK_FACE_VARIANTS = ("full", "barycentric", "ptm", "hsh")


def run(out: Path, quick: bool = False, progress: bool = True, rti: Path | None = None,
        faces: Path | None = None) -> dict:
    """The whole benchmark; writes ``out/bench.json``, ``out/report.md`` and PNG plots.

    rti : a folder with ``Dome/`` (the lights a bundle is built from) and ``Test/`` (held-out
    photos), each an RTI image set with ``dirs.lp``; None or missing skips the real-data part.
    faces : a folder of real faces, one RTI set per subject (``../shared/data/faces-yale``);
    ``quick`` takes ``QUICK_FACES`` of them with ``QUICK_FACE_VARIANTS``.
    """
    from relight.bench.stability import run_stability

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    envs = environments(out / "envs")
    scenes = []
    for scene in QUICK_SCENES if quick else SCENES:
        cfg, cap = synthesize_scene(out / "cache", scene, envs, progress)
        if progress:
            print(f"capturing {scene['name']} with {len(VARIANTS)} variants ...", flush=True)
        bundles = build_variants(cap / "capture.mp4", out / "bundles" / slug(scene["name"]), progress=progress)
        if progress:
            print(f"evaluating {scene['name']} ...", flush=True)
        scenes.append(evaluate_scene(cfg, cap, bundles, envs, out, scene["name"], progress))
    dome = None
    if rti is not None and (rti / "Dome" / "dirs.lp").exists() and (rti / "Test" / "dirs.lp").exists():
        if progress:
            print(f"real held-out photos ({rti}) ...", flush=True)
        dome = evaluate_dome(rti / "Dome", rti / "Test", out, progress, scale=2 if quick else 1)
    face_rows = []
    subjects = face_subjects(faces)
    if quick:
        subjects = [p for p in subjects if p.name in QUICK_FACES]
    for subject in subjects:
        if progress:
            print(f"real face {subject.name} ...", flush=True)
        face_rows.append(evaluate_face(subject, out / "faces", progress,
                                       variants={k: VARIANTS[k] for k in QUICK_FACE_VARIANTS} if quick else None))
    if progress:
        print("numerical stability suite ...", flush=True)
    stability = run_stability()
    doc = {"quick": quick, "envs": {k: {"source": s, "kind": kind} for k, (s, kind) in envs.items()},
           "scenes": scenes, "dome": dome,
           "dome_skipped": None if dome else f"no RTI set with Dome/ and Test/ at {rti}",
           "faces": face_rows, "faces_summary": summarise_faces(face_rows),
           "faces_skipped": None if face_rows else f"no subject folders with dirs.lp at {faces}",
           "stability": stability, "olat_grid": list(OLAT_GRID)}
    doc["summary"] = summarise(doc)
    doc["seconds"] = time.perf_counter() - t_all
    _write_json(out / "bench.json", doc)
    pareto_plot(doc, out / "error_vs_time.png")
    (out / "report.md").write_text(report_markdown(doc))
    return doc


def _write_json(path: Path, doc: dict) -> None:
    from relight.imageio import atomic_path

    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1))
