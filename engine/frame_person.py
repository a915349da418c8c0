"""The frame path's person (region person, mode transfer): when the person's maps
(:mod:`.person_maps`) are made - every few frames, on a worker beside a live source's frames -
reused, and carried with the head (:class:`PersonMixin`).
"""
from __future__ import annotations

from . import head_light
from .person_maps import PersonInputs, PersonMaps, build_person_maps, environment_texels, person_inputs, union_box


class PersonMixin:
    """:class:`relight.engine.frame_path.FramePath`'s person part. Reads the path's ``rig``,
    ``compositor``, ``bundle``, ``env``, ``strength``, ``fixed_env``, ``live_source`` and its
    ``_worker()`` and ``_texel_light()``; keeps (set by the path, dropped with a new environment or
    a reset) ``person`` (the matte model, made on first use), ``_person_last`` (work size,
    :class:`PersonMaps`, the back() call that last used them), ``_person_age`` (frames they were
    reused since made), ``_trust_run`` (the matte's trusted remakes in a row), ``_person_job`` (maps
    being made on the worker) and ``_env_texels`` (the environment's low frequencies); ``_backs``
    counts the path's back() calls."""

    def _last_person(self):
        """The person's maps (work size, :class:`PersonMaps`, the back() call that used them) if
        the last back() call used them - they serve only the call right after (not across a frame
        the person was left out of: no face, another mode, strength 0) - else None."""
        last = self._person_last
        return last if last is not None and last[2] == self._backs - 1 else None

    def _person(self, frame, face_box, coarse, rotation, tau: float, anchor, still: bool, every: int):
        """(:class:`PersonMaps` of this frame, the frame's box the face and the person reach): the
        maps (smooth, slow to change) made every ``every`` frames (:data:`.frame_path.PERSON_EVERY`)
        and reused between, kept while the head is ``still`` (the face's own alpha in the kernel is
        this frame's). With ``live_source`` the making (all but the inputs the device and this thread's state give,
        :meth:`_person_inputs`) runs on a worker: the frame uses the newest maps made, a frame or
        two old, and the next are made while it is composited. ``frame``: as given (an array or a
        YuvFrame); ``face_box``: the face's box in it; ``anchor``: the head's place in it (maps
        made on another frame are carried with the head: :meth:`PersonMaps.moved`)."""
        from .person import WORK_ROWS

        h, w = frame.shape[:2]
        sc = min(1.0, WORK_ROWS / h)
        work = (max(1, round(w * sc)), max(1, round(h * sc)))
        last = self._last_person()
        job = self._person_job  # the maps being made on the worker, or None
        if last is None or last[0] != work:  # none to go on with: made now, on this thread
            if job is not None:  # made for maps no longer in use (another environment, a gap,
                job.result()     # a reset): dropped once done - the model is one, never two at once
                self._person_job = None
            maps = self._took_maps(build_person_maps(self._matte(), self._person_inputs(
                frame, face_box, coarse, rotation, tau, work, anchor)))
        else:
            maps = last[1]
            due = not still and self._person_age + 1 >= every
            if job is not None and job.done():
                self._person_job = None
                maps = self._took_maps(job.result())
            elif due and job is None:
                inputs = self._person_inputs(frame, face_box, coarse, rotation, tau, work, anchor)
                if self.live_source:
                    self._person_job = self._worker().submit(build_person_maps, self._matte(), inputs)
                    self._person_age += 1
                else:
                    maps = self._took_maps(build_person_maps(self._matte(), inputs))
            else:
                self._person_age += 1
        self._person_last = (work, maps, self._backs)
        maps = maps.moved(anchor)
        if maps.box is None:
            return maps, face_box
        x0, y0, x1, y1 = union_box(face_box, maps.box)
        return maps, (max(x0, 0), max(y0, 0), min(x1, w), min(y1, h))

    def _took_maps(self, made) -> PersonMaps:
        """The maps :func:`build_person_maps` made, taken into use on this thread: the matte's run
        of trusted remakes counted and the gate set from it."""
        maps, trusted = made
        self._trust_run = self._trust_run + 1 if trusted else 0
        self._person_age = 0
        return maps._replace(gate=self._trust_run >= head_light.MATTE_TRUST_RUN)

    def _matte(self):
        from .person import PersonMatte

        if self.person is None:
            self.person = PersonMatte()
        return self.person

    def _person_inputs(self, frame, box, coarse, rotation, tau: float, work, anchor) -> PersonInputs:
        """What the person's maps are made of (:func:`.person_maps.person_inputs`) from this frame
        and this path's state."""
        if self._env_texels is None:  # the environment's low frequencies
            self._env_texels = environment_texels(self.env)
        return person_inputs(self.rig, self.compositor, frame, box, coarse, rotation, tau, work, anchor,
                             strength=self.strength, env_texels=self._env_texels, fixed_env=self.fixed_env,
                             texel_dirs=self.bundle.texel_dirs, texel_light=self._texel_light())
