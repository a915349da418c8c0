"""What runs on a frame, and why: the per-frame path's one scheduler (STYLE 21: rates, not
frames).

Every frame with a face is tracked (a small grey copy of the face's neighbourhood), its head
pose solved and the light field applied to it at full resolution, in the decoder's planes. The
rest runs at its own rate, when a cheap test says its input changed - a still head in a still
room costs the tracking and the one pass over the frame:

=============  ============================================================================
stage          runs when (:meth:`Scheduler.plan`)
=============  ============================================================================
relight        a field is made and the environment or the exposure changed, or the head
               turned RELIGHT_DEG since the last relight (the relit face feeds the field
               alone: else the last one serves)
light          mode transfer: no live light yet; the face's brightness moved LIGHT_STEP
               since the last fit (a lamp, the camera's exposure); LIGHT_EVERY frames
               passed while the head moves (LIGHT_SETTLE_EVERY while the exposure settles:
               its first fits); or LIGHT_MAX_AGE frames passed
person         region person: no maps yet; a new environment; the head moved PERSON_MOVE
               of its size or turned PERSON_DEG since they were made; the scene changed in
               the person's box (arms, shoulders, a hand: SCENE_STEP); or PERSON_MAX_AGE
               frames passed
field          the light, the person's maps, a setting or the environment changed; the head
               turned FIELD_JUMP_DEG since it was made, or FIELD_DEG and FIELD_EVERY frames
               passed; its size changed FIELD_SIZE (a translation is carried:
               :meth:`.field.LightField.moved`); the scene changed in the field's box; or
               FIELD_MAX_AGE frames passed
=============  ============================================================================

Where they run: in the frame for files and single requests (runs are repeatable); for a live
source (``relight live``, the service's streams) with a field in use, beside the frames - the
stages a plan names run on a worker (:meth:`.frame_path.FramePath._field_work`), frames go on
with the field in use carried with the head, and no plan is made until the worker's field is
taken (a stage is marked as run at the frame it ran for). A change the user asked for (a
setting, the light, the exposure) is made in the frame: it shows at once.

"The scene changed in a box": the mean absolute difference of a grey thumbnail of the frame
(:data:`THUMB_ROWS` rows, made from the tracking copy) over the box, against the thumbnail of
the frame the stage last ran on, is SCENE_STEP codes or more. A still head in a still room runs
nothing but the tracking and the one pass over the frame, and its output holds still.

:class:`Scheduler` keeps what the tests compare against (the head, the face's brightness and
the frame count when each stage last ran) and returns a :class:`Plan`: each stage's reason to
run this frame, or None.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from relight.numerics import EPS

#: Head turns (degrees) below which the last relight serves (the environment and exposure
#: unchanged): measured on a 960x540 capture, a turn of 0.1 deg changes the relit face by at most
#: 0.17 % (relative L2; a point light beside the face, the sharpest case; 0.07-0.13 % under the
#: built-in environments) - a sixth of the default tolerance. The map's texels are 5.6 deg wide:
#: the error grows linearly, ~1.7 % per degree at worst.
RELIGHT_DEG = 0.1
#: Mode transfer's live light: refitted when the face's mean brightness (the tracking copy's
#: grey codes) moves this share since the last fit; every LIGHT_EVERY frames while the head
#: moves, every LIGHT_SETTLE_EVERY while the exposure settles (its first LIGHT_SETTLE fits: the
#: exposure lock's, :data:`.gains.EXPOSURE_LOCK_FITS`); at least every LIGHT_MAX_AGE frames.
LIGHT_STEP = 0.04
LIGHT_EVERY = 4
LIGHT_SETTLE_EVERY = 3
LIGHT_SETTLE = 8
LIGHT_MAX_AGE = 60
#: The person's maps: remade when the head moved this share of its size (the face's box
#: diagonal) or turned PERSON_DEG since they were made, or after PERSON_MAX_AGE frames.
PERSON_MOVE = 0.08
PERSON_DEG = 6.0
PERSON_MAX_AGE = 150
#: The light field: remade when the head turned FIELD_JUMP_DEG since it was made, or FIELD_DEG
#: once FIELD_EVERY frames passed (between, it is carried with the head), or its size changed
#: FIELD_SIZE (a share), or after FIELD_MAX_AGE frames.
#:
#: The rates (FIELD_EVERY, LIGHT_EVERY, PERSON_DEG) were chosen on the live-frame truth clips,
#: whose heads turn 1-4 deg a frame - far faster than a head on a call: at 2 / 4 / 6 the
#: person's PSNR moved -0.19 to +0.14 dB against a field made on every frame (3 / 6 / 4:
#: -0.04 to -0.27 dB; the person's maps at 8 deg: -0.4 to -1.1 dB and a smear off the person),
#: while the field was made on 65-68 % of the frames and the light fitted on 30 % (docs/performance.md).
FIELD_DEG = 0.25
FIELD_EVERY = 2
FIELD_JUMP_DEG = 2.0
FIELD_SIZE = 0.01
FIELD_MAX_AGE = 150
#: The scene's test: a grey thumbnail of this many rows, and the mean change over a box (8-bit
#: codes) that counts as the scene changing there (a still room's sensor noise averages out at
#: this scale: ~0.3 code; a hand or a shoulder moving into the box, several).
THUMB_ROWS = 36
SCENE_STEP = 3.0


@dataclass(frozen=True)
class Head:
    """Where the head is in a frame: ``anchor`` (x, y) frame px, ``rotation`` (3x3, smoothed),
    ``size`` (px: the face box's diagonal), ``brightness`` (the face's mean grey code in the
    tracking copy: the cheap test of the room's light and the camera's exposure) and ``thumb``
    the frame's grey thumbnail ((h, w) uint8, :data:`THUMB_ROWS` rows; None: no scene test) with
    ``thumb_scale`` its px per frame px."""

    anchor: tuple[float, float]
    rotation: np.ndarray
    size: float
    brightness: float
    thumb: np.ndarray | None = None
    thumb_scale: float = 1.0


@dataclass(frozen=True)
class Plan:
    """Each stage's reason to run on this frame (None: it does not; the last result serves)."""

    relight: str | None = None
    light: str | None = None
    person: str | None = None
    field: str | None = None

    def ran(self) -> dict:
        """{stage: reason} of the stages that run."""
        return {k: v for k, v in (("relight", self.relight), ("light", self.light), ("person", self.person),
                                  ("field", self.field)) if v is not None}


def turned_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (degrees) between two rotations."""
    c = (float(np.trace(np.asarray(a, np.float64).T @ np.asarray(b, np.float64))) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _moved(a: Head, b: Head) -> float:
    """How far the head moved between ``a`` and ``b``, as a share of its size."""
    return float(np.hypot(a.anchor[0] - b.anchor[0], a.anchor[1] - b.anchor[1])) / max(a.size, EPS)


@dataclass
class Mark:
    """When a stage last ran: the head then and the frame's number."""

    head: Head | None = None
    frame: int = -(1 << 30)


@dataclass
class Scheduler:
    """The table of the module docstring, over the marks it keeps (:meth:`ran` sets them)."""

    frame: int = 0
    marks: dict = field(default_factory=lambda: {k: Mark() for k in ("relight", "light", "person", "field")})
    last_head: Head | None = None

    def plan(self, head: Head, *, relight_key_changed: bool, light_wanted: bool, has_light: bool,
             person_wanted: bool, has_person: bool, new_environment: bool, settings_changed: bool,
             relight_deg: float = RELIGHT_DEG, has_field: bool = True, light_fits: int = 1 << 30,
             person_box=None, field_box=None) -> Plan:
        """This frame's :class:`Plan` for a frame whose head is ``head``. ``relight_key_changed``:
        the environment or exposure differ from the last relight's; ``light_wanted``: mode
        transfer; ``has_light``: a live light is in use; ``person_wanted``: region person (and
        strength > 0); ``has_person``: maps are in use; ``new_environment``: the target changed
        since the person's maps were made; ``settings_changed``: strength, mode or the draft
        changed since the field was made (or a slow stage beside the frames delivered);
        ``relight_deg``: the turn that relights (the path's ``reuse_deg``); ``has_field``: a field
        is in use (none: it is made); ``light_fits``: the live light's fits so far (the first
        LIGHT_SETTLE come every LIGHT_EVERY frames); ``person_box``, ``field_box``: the frame's
        boxes (x0, y0, x1, y1) the person's maps and the field reach (the scene's test)."""
        m = self.marks
        light = None
        if light_wanted:
            light = ("first" if not has_light else self._brightness(head, m["light"])
                     or self._aged(m["light"], LIGHT_MAX_AGE)
                     or self._every(head, m["light"], settling=light_fits < LIGHT_SETTLE))
        person = None
        if person_wanted:
            person = ("first" if not has_person else "new light" if new_environment
                      else self._moved_share(head, m["person"], PERSON_MOVE) or self._turned(head, m["person"],
                                                                                              PERSON_DEG)
                      or self._scene(head, m["person"], person_box) or self._aged(m["person"], PERSON_MAX_AGE))
        fld = ("first" if m["field"].head is None or not has_field else "settings" if settings_changed
               else "new light" if relight_key_changed
               else f"{'light' if light else 'person'} ran" if light or person
               else self._field_turned(head, m["field"]) or self._resized(head, m["field"])
               or self._scene(head, m["field"], field_box) or self._aged(m["field"], FIELD_MAX_AGE))
        # the relight feeds the field alone (and the live light's fit, which makes a field): it
        # runs when a field is made and the head turned since the last relight
        relight = None
        if fld is not None:
            relight = "new light" if relight_key_changed else self._turned(head, m["relight"], relight_deg)
        return Plan(relight=relight, light=light, person=person, field=fld)

    def ran(self, stage: str, head: Head, frame: int | None = None) -> None:
        """Mark ``stage`` as run with ``head`` on the frame ``frame`` (None: this one; a stage run
        beside the frames is marked at the frame it ran for)."""
        self.marks[stage] = Mark(head, self.frame if frame is None else int(frame))

    def next_frame(self) -> None:
        self.frame += 1

    def reset(self) -> None:
        """Forget every mark (a new, unrelated video follows)."""
        self.marks = {k: Mark() for k in self.marks}

    # ------------------------------------------------------------------ the tests
    def _turned(self, head: Head, mark: Mark, deg: float) -> str | None:
        if mark.head is None:
            return "first"
        t = turned_deg(head.rotation, mark.head.rotation)
        return f"turned {t:.2f} deg" if t >= deg else None

    def _field_turned(self, head: Head, mark: Mark) -> str | None:
        """The field's turn test: FIELD_JUMP_DEG at once; FIELD_DEG once FIELD_EVERY frames passed
        since it was made (between, the field is carried: :meth:`.field.LightField.moved`)."""
        t = turned_deg(head.rotation, mark.head.rotation)
        age = self.frame - mark.frame
        if t >= FIELD_JUMP_DEG or (t >= FIELD_DEG and age >= FIELD_EVERY):
            return f"turned {t:.2f} deg in {age} frames"
        return None

    def _moved_share(self, head: Head, mark: Mark, share: float) -> str | None:
        if mark.head is None:
            return "first"
        d = _moved(head, mark.head)
        return f"moved {d:.2f} of its size" if d >= share else None

    def _resized(self, head: Head, mark: Mark) -> str | None:
        r = abs(head.size / max(mark.head.size, EPS) - 1.0)
        return f"size {r:+.1%}" if r >= FIELD_SIZE else None

    def _aged(self, mark: Mark, frames: int) -> str | None:
        age = self.frame - mark.frame
        return f"{age} frames old" if age >= frames else None

    def _every(self, head: Head, mark: Mark, settling: bool = False) -> str | None:
        """Every LIGHT_EVERY frames while the head moves (turned or moved since the mark), or every
        LIGHT_SETTLE_EVERY while ``settling``."""
        frames = LIGHT_SETTLE_EVERY if settling else LIGHT_EVERY
        if self.frame - mark.frame < frames or mark.head is None:
            return None
        if settling:
            return f"settling, {self.frame - mark.frame} frames"
        if turned_deg(head.rotation, mark.head.rotation) >= RELIGHT_DEG or _moved(head, mark.head) >= 0.01:
            return f"head moving, {self.frame - mark.frame} frames"
        return None

    def _scene(self, head: Head, mark: Mark, box) -> str | None:
        """The scene changed in ``box`` (frame px) since the mark (module docstring)."""
        if box is None or mark.head is None or head.thumb is None or mark.head.thumb is None \
                or head.thumb.shape != mark.head.thumb.shape:
            return None
        s = head.thumb_scale
        th, tw = head.thumb.shape
        x0, y0 = max(int(box[0] * s), 0), max(int(box[1] * s), 0)
        x1, y1 = min(int(np.ceil(box[2] * s)), tw), min(int(np.ceil(box[3] * s)), th)
        if x1 <= x0 or y1 <= y0:
            return None
        d = cv2.absdiff(head.thumb[y0:y1, x0:x1], mark.head.thumb[y0:y1, x0:x1])
        change = float(cv2.mean(d)[0])
        return f"scene changed {change:.1f} codes" if change >= SCENE_STEP else None

    def _brightness(self, head: Head, mark: Mark) -> str | None:
        if mark.head is None:
            return "first"
        b0, b1 = mark.head.brightness, head.brightness
        step = abs(b1 - b0) / max(b0, 1.0)
        return f"brightness {step:+.1%}" if step >= LIGHT_STEP else None


def thumbnail(grey: np.ndarray) -> np.ndarray:
    """The scheduler's grey thumbnail of a frame (:data:`THUMB_ROWS` rows) from its
    tracking copy ``grey``."""
    from relight.video_yuv import downscale_area

    h, w = grey.shape
    th = min(THUMB_ROWS, h)
    return downscale_area(grey, (max(1, round(w * th / h)), th))


def face_brightness(grey: np.ndarray, xy: np.ndarray) -> float:
    """The mean grey code of the tracking copy ``grey`` over the box of the tracked points ``xy``
    (the face): the scheduler's cheap test of the room's light and the camera's exposure."""
    h, w = grey.shape
    x0, y0 = (int(np.clip(v, 0, m - 1)) for v, m in zip(xy.min(axis=0), (w, h), strict=True))
    x1, y1 = (int(np.clip(v, 0, m - 1)) + 1 for v, m in zip(xy.max(axis=0), (w, h), strict=True))
    return float(cv2.mean(grey[y0:y1, x0:x1])[0]) if x1 > x0 and y1 > y0 else 0.0
