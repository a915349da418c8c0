"""The bundles ``relight bench accuracy`` compares: one capture's preparation shared by every
variant (:data:`relight.bench.variants.VARIANTS`), one bundle per variant from the same
samples and geometry, timed; and a bundle's size as written by default."""

from __future__ import annotations

import copy
import time
from pathlib import Path

from .variants import VARIANTS


def build_variants(source, out_dir: Path, *, images: bool = False, variants=None, progress: bool = False,
                   transfer: str = "srgb") -> dict:
    """Prepare ``source`` once (a capture video, or an RTI folder with ``images``, its files encoded
    with ``transfer``) and write one bundle per variant to ``out_dir``: name -> {"bundle",
    "capture_s", "prepare_s", "bundle_mb"}."""
    from relight.pipeline.bundle_arrays import finish
    from relight.pipeline.bundle_write import write_bundle
    from relight.pipeline.capture_progress import Progress
    from relight.pipeline.capture_types import CaptureOptions
    from relight.pipeline.image_set import prepare_images
    from relight.pipeline.video_source import prepare_video

    variants = VARIANTS if variants is None else variants
    out_dir.mkdir(parents=True, exist_ok=True)
    bar = Progress(progress)
    timings: dict = {}
    t0 = time.perf_counter()
    prepare = prepare_images if images else prepare_video
    prep = prepare(source, CaptureOptions(transfer=transfer).validate(), bar, timings)
    prepare_s = time.perf_counter() - t0
    rows = {}
    try:
        for name, kw in variants.items():
            # The maps kept (the exact path starts at once); the default bundle, its recipe, is
            # measured from the same file (Bundle.default).
            opts = CaptureOptions(**(kw | {"keep_maps": True})).validate()
            mine = copy.copy(prep)
            mine.images = prep.images.copy()  # finish() releases the images it was given
            t1 = time.perf_counter()
            arrays, meta, _, _ = finish(mine, opts, bar, {})
            meta["rejected"] = prep.report.get("rejected", {})
            path = write_bundle(out_dir / f"{name.replace(' ', '_')}.bundle", meta, arrays)
            own = time.perf_counter() - t1
            rows[name] = {"bundle": str(path), "prepare_s": prepare_s, "capture_s": prepare_s + own,
                          "maps_s": own, "bundle_mb": path.stat().st_size / 1e6}
    finally:
        bar.close()
    return rows


def kb_per_px(b) -> float | None:
    """KB per face pixel of the bundle as written by default (its recipe, no maps), or None."""
    return b.default_nbytes / 1e3 / max(b.n_pixels, 1) if b.recipe_stored else None
