"""The frame path's live light (mode transfer): fitted to the face when the scheduler says so
(:mod:`.schedule`) - on a worker beside a live source's frames - taken into use (the face relit
under it for the layer and the tracker's live-lit reference), and the target brought to its
exposure (:class:`LiveLightStage`, the one object holding that state).
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from . import composite
from .frame_data import LayerLight
from .frame_warp import sample_live
from .gains import ExposureLock, ambient_gain, live_gain
from .live_light import LightEstimator, LiveLight, shared_basis
from .tracking_image import lit_reference


def sync_relight(relighter, tm: dict) -> float:
    """Wait for ``relighter``'s queued relight; the ms waited are counted in the frame's relight
    stage (``tm['relight']``) and returned."""
    t = time.perf_counter()
    relighter.sync()
    ms = (time.perf_counter() - t) * 1e3
    tm["relight"] = tm.get("relight", 0.0) + ms
    return ms


class LiveLightStage:
    """Mode transfer's live light in a :class:`relight.engine.frame_path.FramePath`: the fits, the
    light in use, the exposure lock and the live-lit reference for the tracker. It reads the
    path's ``rig``, ``relighter`` and ``tracker`` (given once, with the ``bundle`` its estimator
    is made from) and the ``worker``
    (:class:`.threads.Worker`, shared with the person's stage: one job at a time); it owns (and
    :meth:`reset` drops) ``estimator`` (:class:`.live_light.LightEstimator`), ``last`` (the last
    fit's :class:`.live_light.LiveLight` report), ``now`` ((texel light, spread) of the last fit
    taken, None before one), ``job`` (a fit being made on the worker), ``exposure_lock`` and
    ``next_reference`` (a live-lit reference kept for :meth:`commit_reference`). ``live_source``:
    whether the frames come from a live source now (the path's settings, read each time); then
    fits after the first are made on the worker."""

    def __init__(self, bundle, rig, relighter, tracker, worker, *, live_source: Callable[[], bool]):
        self.rig, self.relighter, self.tracker, self.worker = rig, relighter, tracker, worker
        self.live_source = live_source
        self.estimator = LightEstimator(basis=shared_basis(bundle, rig.live_pixels, relighter.sample_scale))
        self.last: LiveLight | None = None
        self.now = None
        self.job = None
        self.exposure_lock = ExposureLock()
        self.next_reference = None
        self._reference_lock = threading.Lock()
        self.fits = 0  # fits taken into use since the last reset (the scheduler's settling)

    def ready(self) -> bool:
        """Whether a fit made beside the frames waits to be taken (the field is remade with it)."""
        return self.job is not None and self.job.done()

    def new_environment(self) -> None:
        """A new target: its exposure locked anew."""
        self.exposure_lock = ExposureLock()

    def reset(self) -> None:
        """Forget every fit (a new, unrelated video follows); waits for a fit on the worker (the
        estimator is the worker's until it ends)."""
        if self.job is not None:
            self.job.result()
            self.job = None
        self.estimator.reset()
        self.last, self.now = None, None
        self.next_reference = None
        self.exposure_lock = ExposureLock()
        self.fits = 0

    def transfer(self, rgb, cur, ref, rotation, t: float, flat, tm: dict, track_gain: float, defer: bool,
                 rigid_warp: bool, fit: bool) -> LayerLight:
        """Mode transfer's light for a frame: the live light fitted to its face when ``fit`` (the
        scheduler's say: :mod:`.schedule`; beside a live source's frames, on the worker) and taken
        into use (:meth:`took`), the target exposure-matched to it (:func:`.gains.live_gain`, held
        by the exposure lock) - a :class:`.frame_data.LayerLight`. ``rgb``: the frame ((H, W, 3)
        uint8 sRGB or a YuvFrame), ``cur``, ``ref``: the warp's points in it and in the reference
        (:func:`.frame_warp.face_warp`, ``rigid_warp`` its kind), ``rotation`` the head's, ``t``
        the frame's time, ``flat`` the relit reference frame ((H x W, 3) linear), ``tm`` the
        frame's timings; ``track_gain``, ``defer``: for the live-lit reference
        (:meth:`set_lit_reference`)."""
        t5 = time.perf_counter()
        layer_mode, live_median, tau, eps = composite.LAYER_MODE["transfer"], 0.0, 0.0, float(self.rig.ratio_eps)
        waited = 0.0
        if self.ready():  # a fit made beside the frames, taken into use
            job, self.job = self.job, None
            waited = self.took(job.result(), tm, track_gain, defer)
        if fit and self.job is None:
            lin, valid = sample_live(self.rig, rgb, cur, ref, rotation, rigid_warp)
            if self.live_source() and self.now is not None:
                self.job = self.worker.submit(self.fit, lin, valid, t, rotation)
            else:
                waited += self.took(self.fit(lin, valid, t, rotation), tm, track_gain, defer)
        waited += sync_relight(self.relighter, tm)
        if self.now is not None:
            live_median, gain = live_gain(self.rig, self.relighter.slot("live")[0], flat)
            gain = self.exposure_lock(gain)
            spread = self.now[1]
            tau = composite.DETAIL_SHRINK * spread if np.isfinite(spread) else 0.0
            eps = composite.RATIO_EPS * max(live_median, composite.TINY)
        else:  # no light yet (the first frames showed too little): the capture room's ratio
            layer_mode, gain = "ambient", ambient_gain(self.rig, flat)
        tm["light"] = (time.perf_counter() - t5) * 1e3 - waited
        return LayerLight(layer_mode, gain, live_median, tau, eps, waited)

    def fit(self, lin: np.ndarray, valid: np.ndarray, t: float, rotation: np.ndarray):
        """The live light fitted to a frame's sampled face (:meth:`.live_light.LightEstimator.fit`):
        (its report, (the texel light, its spread) or None before any light). Touches only the
        estimator (a worker's while a fit runs beside the frames: the frame's thread reads the
        snapshot :meth:`took` keeps)."""
        est = self.estimator
        report = est.fit(lin, valid, t, rotation)
        return report, (est.texel_light().copy(), float(est.spread)) if est.light is not None else None

    def took(self, fitted, tm: dict, track_gain: float, defer_reference: bool) -> float:
        """A fit (:meth:`fit`) taken into use on the frame's thread: its snapshot kept, the face
        relit under it for the layer and the tracker's reference; the ms waited for the main
        relight first (counted in the relight stage)."""
        self.last, now = fitted
        if now is None:
            return 0.0
        self.now = now
        self.fits += 1
        waited = sync_relight(self.relighter, tm)  # the main relight first (counted as its stage)
        # The live light through the low-rank part alone (direct=0): no texel row is made for it
        # (a recipe bundle's rows cost ~35 ms each at 100k face pixels and the fitted light's
        # brightest texels change every fit). Measured on the 720p live clip against the exact
        # maps: 0.74 % relative L2 median, 0.94 % max (0.47 / 0.68 % with 8 exact texels) - within
        # the default tolerance and far below the fit's own residual (8-15 % on the real faces).
        lit = self.relighter.relight_texels(now[0], slot="live", direct=0)
        self.set_lit_reference(lit, track_gain, defer_reference)
        return waited

    def texel_light(self) -> np.ndarray:
        """(T, 3) the live light in use, in the bundle's texels (zeros before the first)."""
        return self.now[0] if self.now is not None else self.estimator.texel_light()

    def set_lit_reference(self, lit: np.ndarray, gain: float, defer: bool) -> None:
        """The tracker's reference with the face as the live light shows it (``lit``: the reference
        frame relit by the estimate, linear; ``gain``: the tracking gain of the frame the light was
        fitted to): re-anchoring then matches like with like (:func:`.tracking_image.lit_reference`).
        ``defer``: kept for :meth:`commit_reference` instead of handed to the tracker now."""
        ref = lit_reference(self.tracker.reference, lit, self.rig.lit_box, self.rig.track_face, gain)
        if defer:
            with self._reference_lock:  # (made on a worker beside a live source's frames)
                self.next_reference = ref
        else:
            self.tracker.lit_reference = ref

    def commit_reference(self) -> None:
        """Hand the tracker the live-lit reference a deferred frame made."""
        with self._reference_lock:
            ref, self.next_reference = self.next_reference, None
        if ref is not None:
            self.tracker.lit_reference = ref
