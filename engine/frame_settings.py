"""What a caller chooses about a :class:`relight.engine.frame_path.FramePath`'s frames: one
:class:`FrameSettings` value, every field checked here (an :class:`InputError` saying what to
change), changed while frames run by the path's setters (``set_mode`` ...: a new value each time).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.directions import ENV_SPIN_RANGE_DEG_S, ENV_TURN_RANGE_DEG
from relight.errors import InputError
from relight.kernels.relighter import DEFAULT_TOLERANCE

from . import composite
from .field import FIELD_ROWS
from .schedule import RELIGHT_DEG

#: Head turns (degrees) below which the last relight serves (:data:`.schedule.RELIGHT_DEG`).
REUSE_DEG = RELIGHT_DEG
#: Largest ``reuse_deg`` accepted (degrees).
REUSE_DEG_MAX = 5.0
#: Exposure a caller may add to the relit light, in stops (EV): the light scaled by 2^EV.
EXPOSURE_RANGE_EV = (-20.0, 20.0)
#: The light field's rows a caller may ask for (:data:`.field.FIELD_ROWS`).
FIELD_ROWS_RANGE = (16, 4320)
#: The settings a frame path is made with and keeps (its rig, relighter, workers and field are
#: built from them): :meth:`relight.engine.frame_path.FramePath.update` refuses to change them.
FIXED_AT_START = ("focal", "tolerance", "live_source", "field_rows")


@dataclass(frozen=True)
class FrameSettings:
    """A frame path's settings.

    mode : 'transfer', 'ambient' or 'paste' (:data:`.composite.MODES`). strength : 0-1.
    exposure : stops (EV) added to the relit light. env_turn, env_spin : the environment turned
    about the vertical by degrees, and spun by degrees per second of the frames' time from the
    first frame (:data:`relight.directions.ENV_TURN_RANGE_DEG`: the convention). fixed_env : keep
    the environment still relative to the face (no head-rotation compensation).
    region : 'person' - mode transfer also relights the rest of the person (hair, ears, neck,
    shoulders) from the face's ratio (:mod:`.head_light`, the person's matte from :mod:`.person`) -
    or 'face' (the bundle's face alone). Default :data:`.composite.DEFAULT_REGION`.
    focal : the frames' focal length in pixels, or "ortho" (None: found from the frames, see
    :mod:`.focal`; read when the path is made). tolerance : the relighter's (read when the path
    makes its relighter). reuse_deg : head turns below which the last relight is reused
    (:data:`REUSE_DEG`; 0: never). rigid_warp : the warp's control points are a grid over the face
    moved rigidly by the head pose (the bundle's depth) plus the tracked landmarks (the default),
    instead of the landmarks and an affine ring around them (False: the path before issue 32).
    live_source : the slow stages - the light field with the relight and the layer it is made of
    (once a field is in use), the person's matte and ratio (region person) and the live light's
    fit (mode transfer) - made on worker threads while frames go on with the newest made, carried
    with the head (a frame or two older: a live source's next frame should not wait for them; a
    change the user asks for is still made in the frame); False (files, the service's single
    requests) makes them in the frame that needs them: runs are repeatable.
    field_rows : the light field's rows (:data:`.field.FIELD_ROWS`): a frame is scaled down by the
    even factor that leaves about this many (:func:`.field.field_factor`).
    """

    mode: str = composite.DEFAULT_MODE
    strength: float = 1.0
    exposure: float = 0.0
    env_turn: float = 0.0
    env_spin: float = 0.0
    fixed_env: bool = False
    region: str = composite.DEFAULT_REGION
    focal: float | str | None = None
    tolerance: float = DEFAULT_TOLERANCE
    reuse_deg: float = REUSE_DEG
    rigid_warp: bool = True
    live_source: bool = False
    field_rows: int = FIELD_ROWS

    def __post_init__(self):
        if self.mode not in composite.MODES:
            raise InputError(f"mode {self.mode!r}: use one of {', '.join(composite.MODES)}")
        if self.region not in composite.REGIONS:
            raise InputError(f"region {self.region!r}: use one of {', '.join(composite.REGIONS)}")
        _number(self, "strength", (0.0, 1.0), "strength {}: use a number from 0 to 1")
        lo, hi = EXPOSURE_RANGE_EV
        _number(self, "exposure", EXPOSURE_RANGE_EV, f"exposure {{}}: use stops (EV) between {lo:g} and {hi:g}")
        lo, hi = ENV_TURN_RANGE_DEG
        _number(self, "env_turn", ENV_TURN_RANGE_DEG,
                f"environment turn {{}}: use degrees between {lo:g} and {hi:g}")
        lo, hi = ENV_SPIN_RANGE_DEG_S
        _number(self, "env_spin", ENV_SPIN_RANGE_DEG_S,
                f"environment spin {{}}: use degrees per second between {lo:g} and {hi:g}")
        _number(self, "reuse_deg", (0.0, REUSE_DEG_MAX),
                f"reuse_deg {{}}: use 0 (always relight) to {REUSE_DEG_MAX:g} degrees")
        lo, hi = FIELD_ROWS_RANGE
        rows = self.field_rows
        if isinstance(rows, bool) or not isinstance(rows, int | np.integer) or not lo <= rows <= hi:
            raise InputError(f"field_rows {rows}: use a number of rows from {lo} to {hi}")
        object.__setattr__(self, "field_rows", int(rows))
        for name in ("fixed_env", "rigid_warp", "live_source"):
            object.__setattr__(self, name, bool(getattr(self, name)))

    @property
    def exposure_gain(self) -> float:
        """The relit light's linear scale: 2^exposure."""
        return float(2.0 ** self.exposure)

    @property
    def whole_head(self) -> bool:
        """Whether the rest of the person is relit with the face (region 'person', mode transfer)."""
        return self.region == "person" and self.mode == "transfer"


def _number(settings: FrameSettings, name: str, bounds: tuple[float, float], message: str) -> None:
    """``settings.name`` made a float when it is a finite number within ``bounds``; else the
    InputError of ``message`` (its {} the value)."""
    value = getattr(settings, name)
    try:
        ok = not isinstance(value, bool) and np.isfinite(value) and bounds[0] <= value <= bounds[1]
    except TypeError:
        ok = False
    if not ok:
        raise InputError(message.format(value))
    object.__setattr__(settings, name, float(value))
