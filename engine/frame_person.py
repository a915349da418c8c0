"""The frame path's person (region person, mode transfer): the person's maps
(:mod:`.person_maps`) made when the scheduler says so (:mod:`.schedule`) - on a worker beside a
live source's frames - reused between, and carried with the head (:class:`PersonStage`, the one
object holding that state).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import head_light
from .person_maps import PersonInputs, PersonMaps, build_person_maps, environment_texels, person_inputs, work_copy


@dataclass(frozen=True)
class MapsInUse:
    """The person's maps in use: ``maps`` (:class:`PersonMaps`) made at ``work`` (w, h), the work
    size of the frames they serve (:meth:`PersonStage.work_size`)."""

    work: tuple[int, int]
    maps: PersonMaps


class PersonStage:
    """The person's maps in a :class:`relight.engine.frame_path.FramePath`. It reads the path's
    ``rig``, ``compositor`` and the ``bundle``'s texel directions (given once) and the ``worker``
    (:class:`.threads.Worker`, shared with the live light's stage); it owns ``matte`` (the
    :class:`.person.PersonMatte` model, made on first use), ``last`` (work size and
    :class:`PersonMaps` last made), ``seen`` (the last frame the person was relit on: the maps
    serve only while no frame in between left the person out), ``trust_run`` (the matte's trusted
    remakes in a row), ``job`` (maps being made on the worker), ``early`` (the matte model started
    on this frame's work copy: :meth:`start_matte`), ``env_texels`` (the environment's low
    frequencies) and ``frames`` (the path's frames counted by :meth:`next_frame`).
    ``live_source``: whether the frames come from a live source now (the path's settings, read
    each time: :meth:`relight.engine.frame_path.FramePath.warm_up` runs them in the frame); then
    maps after the first are made on the worker."""

    def __init__(self, bundle, rig, compositor, worker, *, live_source: Callable[[], bool]):
        self.rig, self.compositor, self.worker = rig, compositor, worker
        self.texel_dirs = bundle.texel_dirs
        self.live_source = live_source
        self.matte = None
        self.last: MapsInUse | None = None
        self.seen = -2
        self.trust_run = 0
        self.job = None
        self.early = None  # (frame, work size, work copy, Future of the model's probability)
        self.env_texels = None
        self.frames = 0

    def next_frame(self) -> None:
        """Count a frame of the path (every back() call, with or without the person)."""
        self.frames += 1
        self._drop_early()

    @staticmethod
    def work_size(frame) -> tuple[int, int]:
        """The (w, h) the person's maps of ``frame`` are made at (:data:`.person.WORK_ROWS` rows)."""
        from .person import WORK_ROWS

        h, w = frame.shape[:2]
        sc = min(1.0, WORK_ROWS / h)
        return max(1, round(w * sc)), max(1, round(h * sc))

    def makes_now(self, frame, due: bool) -> bool:
        """Whether :meth:`maps` would make the maps on the frame's own thread: none serve at this
        frame's work size, or they are due and the path is not a live source."""
        last = self.last_maps()
        if last is None or last.work != self.work_size(frame):
            return self.job is None or self.job.done()
        return due and self.job is None and not self.live_source() and not self.ready()

    def start_matte(self, frame) -> None:
        """Start the matte model on ``frame``'s work copy on the worker, while the frame's thread
        fits the live light (:meth:`maps` made in the frame then takes it: the two cores share a
        single request's slow stages). Call only when :meth:`makes_now`; dropped unused at the
        next frame."""
        work = self.work_size(frame)
        small = work_copy(frame, work)
        matte = self._matte()
        self.early = (frame, work, small, self.worker.submit(matte.probability, small))

    def _drop_early(self) -> None:
        early, self.early = self.early, None
        if early is not None:
            early[3].result()  # (the model is one: never two runs at once)

    def touch(self) -> None:
        """This frame relights the person (with new maps or the last ones, carried)."""
        self.seen = self.frames

    def new_environment(self) -> None:
        """A new target: the maps made for the last one are not used again (their ratio was its)."""
        self.env_texels = None
        self.last = None

    def light_moved(self) -> None:
        """The same light moved: the maps are remade when next due (on the worker beside a live
        source's frames), the last ones serving until then."""
        self.env_texels = None

    def reset(self) -> None:
        """Forget the maps and the matte's trust (a new, unrelated video follows)."""
        self._drop_early()
        self.last, self.trust_run = None, 0

    def ready(self) -> bool:
        """Whether maps made beside the frames wait to be taken (the field is remade with them)."""
        return self.job is not None and self.job.done()

    def last_maps(self) -> MapsInUse | None:
        """The :class:`MapsInUse` last made if they still serve - the person was relit on
        the frame before this one (not across a frame it was left out of: no face, another mode,
        strength 0) - else None."""
        return self.last if self.last is not None and self.seen >= self.frames - 1 else None

    def maps(self, frame, face_box, coarse, rotation, tau: float, anchor, due: bool, *, env, strength: float,
             fixed_env: bool, texel_light, env_rotation=None) -> PersonMaps:
        """The person's :class:`PersonMaps` for this frame, carried to the head at ``anchor``
        (:meth:`PersonMaps.moved`): made when none serve, or when ``due`` (the scheduler's say) -
        with ``live_source`` on the worker (all but the inputs the device and this thread's state
        give, :meth:`inputs`; the frame goes on with the last ones and the next frame takes the
        new) - else the last ones. ``frame``: as given (an array or a YuvFrame); ``face_box``:
        the face's box in it; ``env``, ``strength``, ``fixed_env``, ``env_rotation`` (3x3 or None):
        the path's target; ``texel_light``: a callable giving the live light in use ((T, 3) in
        the bundle's texels)."""
        work = self.work_size(frame)
        target = dict(env=env, strength=strength, fixed_env=fixed_env, texel_light=texel_light,
                      env_rotation=env_rotation)
        last = self.last_maps()
        self.touch()
        early = self.early
        if early is not None and (early[0] is not frame or early[1] != work):
            early = None
        small, prob = (early[2], early[3]) if early is not None else (None, None)

        def make():
            return self.inputs(frame, face_box, coarse, rotation, tau, work, anchor, small=small, **target)

        if last is None or last.work != work:  # none to go on with: made now, on this thread
            if self.job is not None:  # made for maps no longer in use (another environment, a gap,
                self.job.result()     # a reset): dropped once done - the model is one, never two at once
                self.job = None
            maps = self.took(build_person_maps(self._matte(), make(), prob))
        elif self.ready():
            job, self.job = self.job, None
            maps = self.took(job.result())
        elif due and self.job is None:
            if self.live_source():
                self.job = self.worker.submit(build_person_maps, self._matte(), make())
                maps = last.maps
            else:
                maps = self.took(build_person_maps(self._matte(), make(), prob))
        else:
            maps = last.maps
        self.last = MapsInUse(work, maps)
        return maps.moved(anchor)

    def took(self, made) -> PersonMaps:
        """The maps :func:`build_person_maps` made, taken into use on the frame's thread: the
        matte's run of trusted remakes counted and the gate set from it."""
        maps, trusted = made
        self.trust_run = self.trust_run + 1 if trusted else 0
        return maps._replace(gate=self.trust_run >= head_light.MATTE_TRUST_RUN)

    def _matte(self):
        from .person import PersonMatte

        if self.matte is None:
            self.matte = PersonMatte()
        return self.matte

    def inputs(self, frame, box, coarse, rotation, tau: float, work, anchor, *, env, strength: float,
               fixed_env: bool, texel_light, env_rotation=None, small=None) -> PersonInputs:
        """What the person's maps are made of (:func:`.person_maps.person_inputs`) from this frame,
        the target and this stage's state (``small``: the frame's work copy, when made)."""
        if self.env_texels is None:  # the environment's low frequencies
            self.env_texels = environment_texels(env)
        env_texels = self.env_texels
        if env_rotation is not None:  # the environment turned: its lights at E d
            env_texels = (env_texels[0] @ np.asarray(env_rotation, np.float64).T, env_texels[1])
        return person_inputs(self.rig, self.compositor, frame, box, coarse, rotation, tau, work, anchor,
                             strength=strength, env_texels=env_texels, fixed_env=fixed_env,
                             texel_dirs=self.texel_dirs, texel_light=texel_light(), small=small)
