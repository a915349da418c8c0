"""The per-frame path shared by ``relight filter``, ``relight live`` and the service: track ->
pose -> (relight, live light, person, light field: each at its own rate) -> the field applied.

One flow: a :class:`.rig.FaceRig` (everything the path needs of a bundle, prepared once, frozen),
then, per frame, :meth:`FramePath.front` (track, head pose, warp: a :class:`Front`) and
:meth:`FramePath.back`: the scheduler (:mod:`.schedule`) says which slow stages run on this frame
and why - the relight of the bundle, the live light's fit, the person's maps, the light field
(:mod:`.field`: the face's and the person's change of light as a coarse grid of affine changes of
linear light, made on a copy of the frame scaled to about :data:`.field.FIELD_ROWS` rows) - and the
field, made now or carried with the head, is applied to the frame at its full resolution in one
pass (:class:`relight.kernels.field_apply.FieldApplier`), in the decoder's planes for a
:class:`relight.video_yuv.YuvFrame`. :class:`FramePath` is the one stateful object: its
settings (a :class:`.frame_settings.FrameSettings`), the rig, the relighter, the scheduler, the
environment and the stage objects it owns (:class:`.frame_front.FrontStage`: the tracker, the pose
estimators and filter; :class:`.frame_light.LiveLightStage`, :class:`.frame_person.PersonStage`,
:class:`.frame_field.FieldStage`).
``process(frame, t)`` takes an (H, W, 3) uint8 sRGB frame - or a YuvFrame - and its time in
seconds, and returns the relit frame (the same kind, same size; the input unchanged where no
face is found) and a :class:`FrameInfo`.

Frames of any size work: tracking finds the face wherever it is; the warp maps the bundle's
reference into the frame.
"""
from __future__ import annotations

import time
from dataclasses import replace

import cv2
import numpy as np

from relight.directions import rotation_matrix, with_env_turn
from relight.errors import InputError
from relight.numerics import EPS_VALUE

from . import composite
from .frame_data import Front, LayerLight
from .frame_field import FieldStage
from .frame_front import FrontStage
from .frame_light import LiveLightStage, sync_relight
from .frame_person import PersonStage
from .frame_settings import FIXED_AT_START, FrameSettings
from .gains import ambient_gain, paste_gain
from .pose import OneEuroFilter
from .rig import FaceRig
from .schedule import Head, Plan, Scheduler
from .threads import Worker, limit_threads
from .tracking import FaceTracker

#: One Euro filter setting for the exposure gain (log).
GAIN_MIN_CUTOFF = 0.5


class FramePath:
    """Relights faces in frames with one bundle (see the module docstring).

    settings : a :class:`.frame_settings.FrameSettings` (None: its defaults), changed while frames
    run by the setters (:meth:`set_mode` ...; :attr:`settings` always holds the current one).
    relighter : a :class:`relight.kernels.relighter.Relighter` of the bundle to use (None: one made
    with the settings' tolerance). workers : (field worker, maps worker) - :class:`.threads.Worker` s
    the slow stages run on, shared by several paths (a service's stream clients: one slow stage of
    each kind runs at a time, whoever's it is, and the frames keep the cores); None: the path's own.
    """

    def __init__(self, bundle, env: np.ndarray, settings: FrameSettings | None = None, *, relighter=None,
                 workers: tuple[Worker, Worker] | None = None):
        from relight.kernels.compositor import Compositor
        from relight.kernels.relighter import Relighter

        from .face_subspace import FaceSubspace

        limit_threads()
        settings = FrameSettings() if settings is None else settings
        if not isinstance(settings, FrameSettings):
            raise InputError(f"settings {settings!r}: give a FrameSettings (relight.engine.frame_settings)")
        self.settings = settings
        self.bundle = bundle
        self.relighter = relighter if relighter is not None else Relighter(bundle, tolerance=settings.tolerance)
        # The relit reference frame, filled in place by the relight of each frame (its out=).
        self.relit_frame = np.zeros_like(self.relighter.frame)
        self._field_job = None  # (the Future of _field_work in flight: the setters below join it)
        self.relighter.lights(env)  # a bad environment refused before the rig's seconds of work
        self.env = None
        self.draft = False  # relit as a draft while a light is moved (set_environment(moved=True))
        self.live_light = self.person = None  # (made below, once the rig is)
        self._spin_t0 = None  # the frames' time the spin counts from
        self._relit_key = None  # (env, exposure, turn) of the relight in relit_frame
        self.rig = rig = FaceRig.build(bundle, self.relighter, settings.focal)
        room = bundle.room_light
        subspace = FaceSubspace.from_relighter(self.relighter, rig.solid_full, scale=rig.ref_track_scale,
                                               room=bundle.ambient_frame() if room is not None else None)
        tracker = FaceTracker(rig.track_reference, rig.track_landmarks, rig.track_mask, subspace=subspace)
        live = settings.live_source
        self._own_workers = workers is None  # made here: stopped by close()
        # (field worker: a live source's slow stages beside its frames; maps worker: the person's
        # maps, the live light's fits and the focal search)
        self.workers = workers if workers is not None else \
            (Worker("relight-field", background=live), Worker(background=live))
        # No focal length told: the frames' own is searched for over the first seconds (.focal).
        self.front_stage = FrontStage(rig, tracker, settings.focal is None, self.workers[1])
        # (after the subspace's basis: the environment's rows, made ahead on the device's queue,
        # would hold its two dozen renders back - 1.5 s of a 720p bundle's start)
        self.set_environment(env)
        self.compositor = Compositor(rig.alpha_crop, rig.fill, rig.inv_ambient, rig.normal_crop, rig.origin,
                                     self.relighter)
        # (the stages read the path's settings each time: warm_up's frames run in the frame)
        self.person = PersonStage(bundle, rig, self.compositor, self.workers[1], live_source=self._live_source)
        self.live_light = LiveLightStage(bundle, rig, self.relighter, tracker, self.workers[1],
                                         live_source=self._live_source)
        self.schedule = Scheduler()
        self.field = FieldStage(self.compositor, settings.field_rows)
        self._field_key = None  # the settings the field was made with (:meth:`_plan`)
        self._new_target = True  # a new environment since the person's maps were made
        self.gain_filter = OneEuroFilter(GAIN_MIN_CUTOFF, 0.0)

    # ------------------------------------------------------------------ settings
    def set_environment(self, env: np.ndarray, moved: bool = False) -> None:
        """Relight under ``env`` from the next frame: a frozen copy is kept (the Relighter then
        recognises it without hashing it every frame, and the caller's array stays theirs).
        ``moved``: the same light moved (a key dragged on a page) - mode transfer's locked
        exposure is kept (the face darkens as the key goes to its side, as it would) instead of
        matched anew, the person's maps are remade as when they are due (beside a live source's
        frames; the last ones serve a frame or two) instead of in the next frame, and the face
        is relit as a draft (the low-rank part alone: no texel row made while the light moves)
        until :meth:`settle`."""
        from relight.kernels.relight_inputs import frozen

        self.join()
        env = frozen(env)
        self.relighter.lights(env)  # validates and converts once
        self.env = env
        self.draft = bool(moved)
        if not moved:
            self.relighter.prefetch_rows(env)  # the exact texels' rows, ahead of the head's turns
        if self.live_light is not None:  # (the first environment comes before the stages)
            self._new_target = True  # the person's maps remade for it (on the worker for a live source)
            if moved:
                self.person.light_moved()  # its ratio remade when due, soon
            else:
                self.live_light.new_environment()  # mode transfer's exposure, locked anew
                self.person.new_environment()  # the person's ratio was the last environment's

    def settle(self) -> None:
        """The moved light came to rest: relit in full from the next frame (its exact texels'
        rows made - ahead of the head's turns, on their own thread)."""
        self.join()
        if self.draft:
            self.draft = False
            self._relit_key = None
            self.relighter.prefetch_rows(self.env)

    @property
    def whole_head(self) -> bool:
        """Whether the rest of the person is relit with the face (region 'person', mode transfer)."""
        return self.settings.whole_head

    # The setters wait for the slow stages beside a live source's frames (:meth:`join`: they read
    # the settings) only when a value changes: a caller that sets every frame's settings (the
    # service does) does not make each frame wait for them. Each checks its value as
    # FrameSettings does (an InputError saying what to change; the settings then unchanged).
    def update(self, **changes) -> None:
        """The settings changed (``mode=...``, any of :class:`.frame_settings.FrameSettings`' but
        those the path was made with, :data:`.frame_settings.FIXED_AT_START`) from the next frame.
        ``env_spin`` counts from the next frame's time when it changes."""
        fixed = set(FIXED_AT_START) & changes.keys()
        if fixed:
            raise InputError(f"{', '.join(sorted(fixed))}: set when the frame path is made; make a new one")
        new = replace(self.settings, **changes)
        if new != self.settings:
            self.join()
            if new.env_spin != self.settings.env_spin:
                self._spin_t0 = None
            self.settings = new

    def set_mode(self, mode: str) -> None:
        self.update(mode=mode)

    def set_strength(self, strength: float) -> None:
        self.update(strength=strength)

    def set_exposure(self, ev: float) -> None:
        """The relit light scaled by 2^``ev`` (stops)."""
        self.update(exposure=ev)

    def set_env_turn(self, deg: float) -> None:
        """Turn the environment about the vertical by ``deg`` (:data:`relight.directions.ENV_TURN_RANGE_DEG`)."""
        self.update(env_turn=deg)

    def set_env_spin(self, deg_per_s: float) -> None:
        """Spin the environment about the vertical by ``deg_per_s`` degrees per second of the
        frames' time, from the next frame on (where the turn has it; asked again, the spin counts
        anew from the next frame)."""
        self.update(env_spin=deg_per_s)
        self._spin_t0 = None

    def env_rotation(self, t: float) -> np.ndarray | None:
        """The environment's rotation (3x3, lights moved by it) at frame time ``t``, or None when
        it is not turned (then nothing is composed: the path's numbers are as without it)."""
        if self.settings.env_spin != 0.0:
            if self._spin_t0 is None:
                self._spin_t0 = t
            deg = self.settings.env_turn + self.settings.env_spin * (t - self._spin_t0)
        else:
            deg = self.settings.env_turn
        deg = float(np.remainder(deg + 180.0, 360.0) - 180.0)
        return rotation_matrix(deg, 0.0, 0.0) if deg != 0.0 else None

    @property
    def frames_focal(self) -> float | None:
        """The focal length (px) the frames' poses are solved with now (None before a frame): the
        one told, the default guess, or the one found (:mod:`.focal`)."""
        return self.front_stage.frames_focal

    @property
    def focal_found(self) -> bool:
        """Whether the frames' focal length was found (:mod:`.focal`) rather than told or guessed."""
        return self.front_stage.focal_found

    def close(self) -> None:
        """Wait for the slow stages in flight and stop the worker threads this path made (workers
        given to it are their giver's to stop). The path may not be used after. A slow stage's
        error is not raised here (it was the frames' to report; close runs on the way out of one)."""
        try:
            self.join()
        except Exception:  # (see above)
            pass
        finally:
            if self._own_workers:
                for worker in self.workers:
                    worker.close()

    def __enter__(self) -> FramePath:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def reset(self) -> None:
        """Forget the track and the filters (a new, unrelated video follows)."""
        self.join()
        self.front_stage.reset()
        self.gain_filter.reset()
        self.live_light.reset()
        self.person.reset()
        self.schedule.reset()
        self.field.reset()

    def warm_up(self, size: tuple[int, int] | None = None, planes: bool = True) -> float:
        """Run every kernel and model the frames will (and make PoCL compile each for its work-group
        shape) before the first real frame: the bundle's own reference frame, scaled to ``size``
        (w, h; None: as it is), through the path - RGB and, with ``planes``, in Y'CbCr planes -
        then :meth:`reset`. A live source's first frames then wait for no compile (measured on a
        fresh machine: one frame waited 1.9 s). Returns the seconds it took."""
        from relight.video_yuv import YuvFrame, rgb_to_planes

        t0 = time.perf_counter()
        ref = np.ascontiguousarray(self.bundle.background)
        if size is not None and tuple(size) != (ref.shape[1], ref.shape[0]):
            ref = cv2.resize(ref, tuple(size), interpolation=cv2.INTER_AREA)
        frames = [ref]
        if planes and ref.shape[0] % 2 == 0 and ref.shape[1] % 2 == 0:
            frames.append(YuvFrame(*rgb_to_planes(ref)))
        settings = self.settings  # (the slow maps in the frame: all of them run)
        self.settings = replace(settings, live_source=False)
        try:
            for i, f in enumerate(frames):
                self.reset()
                for k in range(2):
                    self.process(f, (2 * i + k) / 30.0)
        finally:
            self.settings = settings
            self.reset()
        return time.perf_counter() - t0

    def _live_source(self) -> bool:
        """Whether the frames come from a live source now (:attr:`settings`; off while :meth:`warm_up` runs)."""
        return self.settings.live_source

    # ------------------------------------------------------------------ per frame
    def process(self, rgb, t: float):
        """The relit frame and what happened (see the module docstring): :meth:`front` then
        :meth:`back`. ``rgb``: (H, W, 3) uint8 sRGB, or a :class:`relight.video_yuv.YuvFrame` (a
        decoded frame kept in its planes: only the face's box is converted, and a YuvFrame comes
        back)."""
        return self.back(self.front(rgb, t))

    def front(self, rgb, t: float) -> Front:
        """The first half of :meth:`process` - track and head pose - for a frame: what
        :meth:`back` needs. Touches only the tracker, the pose estimator and the angle filter, so
        a caller may run it for the next frame while :meth:`back` runs for this one (on another
        thread: ``defer_reference=True`` there keeps the tracker's live-lit reference for
        :meth:`commit_reference`)."""
        return self.front_stage.front(rgb, t, self.settings)

    def back(self, front: Front, defer_reference: bool = False):
        """The second half of :meth:`process` for the result of :meth:`front`: the scheduler's
        plan (:mod:`.schedule`), the slow stages it names - in this frame, or for a live source
        with a field in use beside the frames (:meth:`_field_work` on a worker: this frame and the
        next go on with the field in use, carried with the head, until it is made; a change the
        user asked for - a setting, the light - is made in the frame: it shows at once) - and the
        light field applied.
        ``defer_reference``: the tracker's live-lit reference kept for :meth:`commit_reference`
        (a caller running :meth:`front` of the next frame meanwhile)."""
        self.person.next_frame()
        self.schedule.next_frame()
        self._take_field(front.info.timings)
        if not defer_reference:
            self.commit_reference()
        if front.pose is None:
            return front.frame, front.info
        info, tm = front.info, front.info.timings
        box = front.warp.box
        if box is None:
            return front.outside()
        anchor = tuple(float(v) for v in front.warp.cur.mean(axis=0))  # the head's place: the field follows it
        head = Head(anchor, front.rotation, float(np.hypot(box[2] - box[0], box[3] - box[1])), front.brightness,
                    front.thumb, front.thumb_scale)
        env_rot = self.env_rotation(front.t)
        # The relighter's rotation: the head's (a head turned by R sees the light from d at R^T d),
        # with the environment's own turn E composed (its lights at E d: seen at R^T E d).
        turn = with_env_turn(None if self.settings.fixed_env else front.rotation, env_rot)
        self.field.check_space(front.frame)
        # (while a field is made beside the frames the stages are the worker's: nothing is planned)
        plan, asked = self._plan(head, turn) if self._field_job is None else (Plan(), False)
        info.ran = plan.ran()
        info.reused = plan.relight is None
        if self.whole_head and self.settings.strength > 0:
            self.person.touch()
        if plan.field is not None and self.settings.live_source and self.field.last is not None and not asked:
            self._field_job = self.workers[0].submit(self._field_work, front, head, plan, env_rot, turn,
                                                        self.schedule.frame, True, {})
        elif plan.field is not None:
            made = self._field_work(front, head, plan, env_rot, turn, self.schedule.frame, defer_reference, tm)
            if made is None:
                return front.outside()
            self._took_field(made)
        if plan.field is None or self._field_job is not None:
            self.field.carry(anchor, front.size)
        if self.settings.mode == "transfer":
            info.light = self.live_light.last
        t4 = time.perf_counter()
        out = self.field.apply(front.frame)
        tm["composite"] = (time.perf_counter() - t4) * 1e3
        tm["total"] = (time.perf_counter() - front.t0) * 1e3
        return out, info

    def _field_work(self, front: Front, head: Head, plan: Plan, env_rot, turn, frame: int, defer: bool, tm: dict):
        """The slow stages ``plan`` names for the frame ``front`` (number ``frame``): the relight,
        the live light, the person's maps and the light field (:meth:`_make_field`). Returns
        (the field made - a :class:`.field.LightField` or None -, the stages that ran, the head,
        ``frame``, ``tm``: the ms they took), or None when the warp's coarse map leaves the frame.
        Touches the relighter, the compositor and the stages, never the tracker (the live-lit
        reference is kept for :meth:`commit_reference` with ``defer``): a live source runs it on a
        worker while frames go on (:meth:`_take_field` takes what it made)."""
        t3 = time.perf_counter()
        coarse = front.warp.coarse()  # the warp's coarse map: made only for a field
        tm["warp"] = tm.get("warp", 0.0) + (time.perf_counter() - t3) * 1e3
        if coarse is None:
            return None
        ran = ["field"]
        t2 = time.perf_counter()
        if plan.relight is not None:  # queued, not waited for: synced before the host reads it
            gain = self.settings.exposure_gain
            self.relighter.relight(self.env, turn, exposure=gain, out=self.relit_frame, wait=False,
                                   direct=0 if self.draft else None)
            self._relit_key = (self.env, gain, turn)
            ran.append("relight")
        tm["relight"] = (time.perf_counter() - t2) * 1e3
        made = self._make_field(front, coarse, head, plan, env_rot, defer, tm, ran, frame)
        return made, ran, head, frame, tm

    def _took_field(self, made, tm: dict | None = None) -> None:
        """What :meth:`_field_work` made taken into use: the field, the scheduler's marks of the
        stages that ran (at the frame they ran for), their ms added to ``tm``."""
        fld, ran, head, frame, job_tm = made
        self.field.last = fld
        for stage in ran:
            self.schedule.ran(stage, head, frame)
        if "person" in ran:
            self._new_target = False
        if tm is not None:
            for k, v in job_tm.items():
                tm[k] = tm.get(k, 0.0) + v

    def _take_field(self, tm: dict | None, wait: bool = False) -> None:
        """A field made beside the frames taken into use once made (``wait``: waited for)."""
        job = self._field_job
        if job is None or not (wait or job.done()):
            return
        self._field_job = None
        made = job.result()
        if made is not None:
            self._took_field(made, tm)

    def join(self) -> None:
        """Wait for the slow stages a live source runs beside its frames (the field, then the
        person's maps and the live light's fit) and take what they made: after it the path's
        state is its own thread's (a setting changed, a reset, a test comparing frames); and for
        the focal search on the maps' worker (its result is taken on the next frame)."""
        if self._field_job is not None:
            self._take_field(None, wait=True)
        self.front_stage.join()

    def _plan(self, head: Head, turn) -> tuple[Plan, bool]:
        """The scheduler's plan for this frame (:meth:`.schedule.Scheduler.plan`) from what the path
        holds: the last relight's key, the live light and the person's maps in use (and those made
        beside the frames, waiting), the settings the field was made with; and whether it answers
        a change the user asked for (a setting, the light, the exposure: shown on this frame, its
        field made in it, never beside the frames)."""
        from relight.kernels.relight_inputs import rotation_angle_deg

        last, s = self._relit_key, self.settings
        key_changed = last is None or last[0] is not self.env or last[1] != s.exposure_gain or \
            (turn is None) != (last[2] is None)
        if not key_changed and turn is not None and s.reuse_deg == 0:
            key_changed = rotation_angle_deg(last[2], turn) > 0  # (reuse_deg 0: every turn relights)
        delivered = self.live_light.ready() or self.person.ready()
        key = (s.mode, s.strength, self.draft, s.exposure_gain, s.region, s.fixed_env, id(self.env))
        asked = key_changed or key != self._field_key
        plan = self.schedule.plan(head, relight_key_changed=key_changed, light_wanted=s.mode == "transfer",
                                  has_light=self.live_light.now is not None,
                                  person_wanted=s.whole_head and s.strength > 0,
                                  has_person=self.person.last_maps() is not None,
                                  new_environment=self._new_target,
                                  settings_changed=key != self._field_key or delivered,
                                  relight_deg=s.reuse_deg, has_field=self.field.last is not None,
                                  light_fits=self.live_light.fits, person_box=self._person_box(),
                                  field_box=self.field.last.box if self.field.last is not None else None)
        self._field_key = key
        self._field_env = self.env  # (kept alive: the id above stays its)
        return plan, asked

    def _person_box(self):
        """The frame's box the person's maps in use reach (None: none in use)."""
        last = self.person.last_maps()
        return last.maps.box if last is not None else None

    def _make_field(self, front: Front, coarse: np.ndarray, head: Head, plan: Plan, env_rot, defer: bool, tm: dict,
                    ran: list, frame: int):
        """The light field of this frame (:mod:`.frame_field`): the face's layer built for it (the
        live light fitted when the plan says), the person's maps (region person: made when the
        plan says, else the last ones carried), then the field over the box they reach (returned:
        a :class:`.field.LightField` or None). ``coarse``: the warp's coarse map (made by the
        caller). The stages that ran are appended to ``ran``, their ms to ``tm``."""
        rgb, t, s = front.frame, front.t, self.settings
        box = front.warp.box
        t3 = time.perf_counter()
        if s.whole_head and s.strength > 0 and not s.live_source and \
                (self.live_light.now is not None or plan.light is not None) and \
                self.person.makes_now(rgb, plan.person is not None):
            # its model beside the live light's fit (a file's frames and single requests: a live
            # source makes its slow stages beside its frames already; before a live light the
            # person's maps are not made at all)
            self.person.start_matte(rgb)
        light = self._light(front, plan, defer, tm, ran)
        gain = float(np.exp(self.gain_filter([np.log(max(light.gain, EPS_VALUE))], t)[0]))
        tm["warp"] = tm.get("warp", 0.0) + (time.perf_counter() - t3) * 1e3 - tm.get("light", 0.0) - light.waited_ms
        live_buf = self.relighter.slot("live")[1] if light.mode == "live" else None
        self.compositor.layer(relit=self.relighter.buffer(self.relit_frame), live=live_buf, mode=light.mode,
                              gain=gain * s.exposure_gain, strength=s.strength, eps=light.eps,
                              ratio_max=composite.RATIO_MAX, rotation=front.rotation, live_median=light.live_median)
        maps = None
        if s.whole_head and light.mode == "live" and s.strength > 0:
            t6 = time.perf_counter()
            maps = self.person.maps(rgb, box, coarse, front.rotation, light.tau, head.anchor, plan.person is not None,
                                    env=self.env, strength=s.strength, fixed_env=s.fixed_env,
                                    texel_light=self.live_light.texel_light, env_rotation=env_rot)
            if plan.person is not None:
                ran.append("person")
            tm["person"] = (time.perf_counter() - t6) * 1e3
        t7 = time.perf_counter()
        made = self.field.made(rgb, box, coarse, light.mode, light.tau, maps, head.anchor, frame)
        tm["field"] = (time.perf_counter() - t7) * 1e3
        return made

    def _light(self, front: Front, plan: Plan, defer: bool, tm: dict, ran: list) -> LayerLight:
        """The layer's light for this frame, by mode (a :class:`.frame_data.LayerLight`): mode
        transfer's live light fitted when the plan says (:meth:`.frame_light.LiveLightStage.transfer`;
        "light" appended to ``ran``)."""
        rgb = front.frame
        cur, ref = front.warp.cur, front.warp.ref
        flat = self.relit_frame.reshape(-1, 3)
        if self.settings.mode == "transfer":
            out = self.live_light.transfer(rgb, cur, ref, front.rotation, front.t, flat, tm, front.track_gain, defer,
                                           self.settings.rigid_warp, plan.light is not None)
            if plan.light is not None:
                ran.append("light")
            return out
        waited = sync_relight(self.relighter, tm)
        if self.settings.mode == "ambient":  # the lighting ratio's median is 1: the face keeps its brightness
            gain = ambient_gain(self.rig, flat)
        else:  # paste: the relit face's median matched to the live face's at the tracked points
            gain = paste_gain(self.rig, rgb, flat, front.track.xy[front.keep], front.ref_idx)
        return LayerLight(composite.LAYER_MODE[self.settings.mode], gain, 0.0, 0.0, float(self.rig.ratio_eps), waited)

    def commit_reference(self) -> None:
        """Hand the tracker the live-lit reference a deferred :meth:`back` made (between frames,
        when no :meth:`front` runs)."""
        self.live_light.commit_reference()
