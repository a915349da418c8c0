"""The frame path's light field (:mod:`.field`): made over the box the face and the person reach,
carried with the head between remakes, and applied to every frame - in the decoder's planes for a
:class:`relight.video_yuv.YuvFrame` (:class:`FieldStage`, the one object holding that state)."""
from __future__ import annotations

import numpy as np

from .field import GAIN_MAX, LightField, aligned_box, cover_box, field_factor, small_copy
from .person_maps import union_box
from .warp import GRID_STEP


def frame_space(frame):
    """What a frame's codes are: "rgb" (sRGB) or a decoded frame's planes' (``YuvFrame.space``)."""
    return "rgb" if isinstance(frame, np.ndarray) else frame.space


class FieldStage:
    """The light field of a :class:`relight.engine.frame_path.FramePath`: it reads the path's
    ``compositor`` (whose layer the path builds before :meth:`make`); it owns the
    :class:`relight.kernels.field_apply.FieldApplier` and ``last``, the field in use (None: none),
    and ``rows``, the field's rows (:func:`.field.field_factor`)."""

    def __init__(self, compositor, rows: int):
        from relight.kernels.field_apply import FieldApplier

        self.compositor = compositor
        self.rows = int(rows)
        self.applier = FieldApplier()
        self.last: LightField | None = None

    def reset(self) -> None:
        self.last = None

    def check_space(self, frame) -> None:
        """Forget the field when ``frame``'s codes are not the ones it maps (frames of another kind)."""
        if self.last is not None and self.last.space != frame_space(frame):
            self.last = None

    def carry(self, anchor, size) -> None:
        """The field in use carried to the head at ``anchor`` (:meth:`.field.LightField.moved`)."""
        if self.last is not None:
            self.last = self.last.moved(anchor, size)

    def made(self, frame, box, coarse, layer_mode: str, tau: float, maps, anchor, index: int):
        """The field of this frame: the compositor's ``person_gain`` kernel (its last layer: this
        frame's) over the box the face (``box``, ``coarse``: the warp) and the person's ``maps``
        (or None: the face alone) reach, on a copy scaled down by the field's factor, as maps of
        ``frame``'s codes: a :class:`.field.LightField`, or None when nothing changes. ``anchor``:
        the head's place; ``index``: the frame's number. Reads the compositor, not ``last``: it
        may run on a worker while the frames carry and apply the field in use."""
        from relight.kernels.field_apply import COVER

        from .head_light import MATTE_FLOOR

        h, w = frame.shape[:2]
        f = field_factor((w, h), self.rows)
        if f == 1 and not isinstance(frame, np.ndarray):
            f = 2  # (a decoded frame's field is made of whole chroma samples)
        reach = box if maps is None or maps.box is None else union_box(box, maps.box)
        ax0, ay0, _, _ = abox = aligned_box(reach, (w, h), f)
        small = small_copy(frame, abox, f)
        face_box = (box[0] - ax0, box[1] - ay0, box[2] - ax0, box[3] - ay0)
        person = {} if maps is None else dict(person=maps.grid, person_origin=maps.origin, person_scale=maps.scale,
                                              floor=MATTE_FLOOR, offset=(ax0, ay0), gate=maps.gate)
        codes = frame.code_maps() if not isinstance(frame, np.ndarray) else (None, None)
        grid = self.compositor.person_gain(small, (0, 0, small.shape[1], small.shape[0]), face_box, coarse,
                                           GRID_STEP, mode=layer_mode, tau=tau, scale=(f, f), gain_max=GAIN_MAX,
                                           code_maps=codes, **person)
        reach_box = cover_box(grid[..., COVER], (ax0, ay0), f, (w, h))
        if reach_box is None:
            return None
        grid.flags.writeable = False
        if not isinstance(frame, np.ndarray):
            self.applier.prepare(grid)  # (laid out for the planes' kernel here: on the worker for a live source)
        return LightField(grid, frame_space(frame), f, (float(ax0), float(ay0)), reach_box, anchor, index)

    def apply(self, frame):
        """``frame`` with the field in use applied (a new frame of the same kind: the field's kernel
        over its box, in the planes of a YuvFrame); the frame as it is without one."""
        fld = self.last
        if fld is None:
            return frame
        if isinstance(frame, np.ndarray):
            return self.applier.rgb(frame, fld.box, fld.grid, fld.factor, fld.corner)
        return frame.with_field(self.applier, fld.box, fld.grid, fld.factor, fld.corner)
