"""What a capture is told and what its halves hand on: :class:`CaptureOptions` (everything
``relight capture`` can be told), :class:`Prepared` (what the front half - :mod:`video_source` or
:mod:`image_set` - gives the back half, :mod:`bundle_arrays`) and :class:`CaptureResult` (what
:func:`relight.pipeline.capture.capture` returns)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from relight.errors import InputError
from relight.kernels.transport import STORE_TOLERANCE

from . import methods
from .ingest import DEFAULT_FACE_PIXELS
from .samples import SampleOptions
from .shading_fit import MODEL_REACH_DEG
from .triangulate import DEFAULT_MAP_SIZE

#: Transfer curves an image set's 8/16-bit files may be encoded with (``relight capture
#: --transfer``): sRGB (phones, cameras' JPEGs, most RTI sets) or linear (a camera's raw response,
#: e.g. the Extended Yale B faces). EXR/HDR files are always linear.
TRANSFERS = ("srgb", "linear")


@dataclass
class CaptureOptions:
    """Everything ``relight capture`` can be told (each stage switchable)."""

    method: str = "full"
    visibility: bool = True
    adaptation: bool = True
    extrapolation: bool = True
    paper_adaptation: bool = False
    spline: bool = True
    model_reach: float = MODEL_REACH_DEG
    map_size: tuple[int, int] = DEFAULT_MAP_SIZE
    samples: SampleOptions = field(default_factory=SampleOptions)
    face: tuple[int, int, int, int] | None = None
    mesh: str | None = None
    export_mesh: str | None = None
    backend: str = "opencl"
    transfer: str = "srgb"
    # --keep-maps: also the pixel-major copy of the maps (the texel-major ``maps_rows`` hold the
    # same values; the exact path gathers from them) and the flash samples (for re-fitting).
    keep_maps: bool = False
    face_pixels: int | None = DEFAULT_FACE_PIXELS
    # --store-tolerance: the finest relight tolerance the compact transport is stored for.
    store_tolerance: float = STORE_TOLERANCE

    def validate(self) -> CaptureOptions:
        methods.validate_method(self.method)
        if self.transfer not in TRANSFERS:
            raise InputError(f"--transfer {self.transfer}: use one of {', '.join(TRANSFERS)}")
        w, h = self.map_size
        if w != 2 * h or not (8 <= h <= 256):
            raise InputError(f"--map-size {w}x{h}: use a 2:1 size between 16x8 and 512x256, e.g. 64x32")
        if not (np.isfinite(self.model_reach) and 0.0 < self.model_reach <= 180.0):
            raise InputError(f"--model-reach {self.model_reach}: use degrees in (0, 180], e.g. 60")
        return self


@dataclass
class Prepared:
    """What the back half of the pipeline starts from (video and image sets alike)."""

    images: np.ndarray          # (K, h, w, 3) linear flash-only samples
    dirs: np.ndarray            # (K, 3)
    clipped: np.ndarray         # (K, h, w) bool
    ambient: np.ndarray         # (h, w, 3) linear
    background: np.ndarray      # (H, W, 3) uint8 sRGB full frame
    origin: tuple[int, int]
    frame_size: tuple[int, int]
    face_local: tuple[int, int, int, int] | None
    mask: np.ndarray | None     # given mask (crop coordinates) or None to estimate
    meta: dict = field(default_factory=dict)
    report: dict = field(default_factory=dict)


@dataclass
class CaptureResult:
    """What ``capture`` produced: the bundle path, report content, per-stage timings (s)."""

    bundle: Path
    report: dict
    timings: dict
    arrays: dict = field(repr=False, default_factory=dict)
    prepared: Prepared | None = field(repr=False, default=None)
    meta: dict = field(repr=False, default_factory=dict)
