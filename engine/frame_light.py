"""The frame path's live light (mode transfer): fitted to the face every few frames - on a
worker beside a live source's frames - taken into use (the face relit under it for the layer and
the tracker's live-lit reference), and the target brought to its exposure (:class:`LiveLightMixin`).
"""
from __future__ import annotations

import time

import numpy as np

from . import composite
from .frame_warp import sample_live
from .gains import ambient_gain, live_gain
from .tracking_image import lit_reference

#: Mode transfer: the live light is fitted every this many frames (it is smoothed over a tenth of a
#: second anyway; the frames between reuse it). Measured against 2: the same figures on the truth
#: clips (+-0.02 dB) and the real faces (+-0.03 dB) at two thirds of the fits; 4 cost 0.1-0.16 dB.
LIGHT_EVERY = 3


class LiveLightMixin:
    """:class:`relight.engine.frame_path.FramePath`'s live light part. Reads the path's ``rig``,
    ``relighter``, ``tracker``, ``live_source``, ``rigid_warp`` and its ``_worker()`` and
    ``_sync_relight()``; keeps (set by the path, dropped by a reset) ``light_estimator``,
    ``_last_light`` (the last fit's report), ``_light_now`` ((texel light, spread) of the last fit
    taken), ``_light_job`` (a fit being made on the worker), ``_since_light`` (frames since the
    last fit), ``_exposure_lock`` (:class:`.gains.ExposureLock`) and ``_next_reference`` (a live-lit
    reference kept for ``commit_reference``)."""

    def _transfer_light(self, rgb, cur, ref, rotation, t: float, flat, tm: dict, track_gain: float, defer: bool):
        """Mode transfer's light for a frame: the live light fitted to its face every
        ``LIGHT_EVERY`` frames (beside a live source's frames, on the worker) and taken into use
        (:meth:`_took_light`), the target exposure-matched to it (:func:`.gains.live_gain`, held by
        the path's exposure lock). ``rgb``: the frame (the converted box of a YuvFrame), ``cur``,
        ``ref``: the warp's points in it and in the reference (:func:`.frame_warp.face_warp`),
        ``rotation`` the head's, ``t`` the frame's time, ``flat`` the relit reference frame
        ((H x W, 3) linear), ``tm`` the frame's timings; ``track_gain``, ``defer``: for the live-lit
        reference (:meth:`_set_lit_reference`). Returns (the layer's mode - 'live', 'ambient' before
        any light -, the gain, the live face's median luminance, the detail threshold tau, the
        ratio's eps, the ms waited for the relight)."""
        t5 = time.perf_counter()
        layer_mode, live_median, tau, eps = composite.LAYER_MODE["transfer"], 0.0, 0.0, float(self.rig.ratio_eps)
        waited = 0.0
        job = self._light_job
        if job is not None and job.done():  # a fit made beside the frames, taken into use
            self._light_job = None
            waited = self._took_light(job.result(), tm, track_gain, defer)
        if job is None and (self._light_now is None or self._since_light + 1 >= LIGHT_EVERY):
            lin, valid = sample_live(self.rig, rgb, cur, ref, rotation, self.rigid_warp)
            self._since_light = 0
            if self.live_source and self._light_now is not None:
                self._light_job = self._worker().submit(self._fit_light, lin, valid, t, rotation)
            else:
                waited += self._took_light(self._fit_light(lin, valid, t, rotation), tm, track_gain, defer)
        else:
            self._since_light += 1
        waited += self._sync_relight(tm)
        if self._light_now is not None:
            live_median, gain = live_gain(self.rig, self.relighter.slot("live")[0], flat)
            gain = self._exposure_lock(gain)
            spread = self._light_now[1]
            tau = composite.DETAIL_SHRINK * spread if np.isfinite(spread) else 0.0
            eps = composite.RATIO_EPS * max(live_median, composite.TINY)
        else:  # no light yet (the first frames showed too little): the capture room's ratio
            layer_mode, gain = "ambient", ambient_gain(self.rig, flat)
        tm["light"] = (time.perf_counter() - t5) * 1e3 - waited
        return layer_mode, gain, live_median, tau, eps, waited

    def _fit_light(self, lin: np.ndarray, valid: np.ndarray, t: float, rotation: np.ndarray):
        """The live light fitted to a frame's sampled face (:meth:`.live_light.LightEstimator.fit`): (its
        report, (the texel light, its spread) or None before any light). Touches only the
        estimator (a worker's while a fit runs beside the frames: the frame's thread reads the
        snapshot :meth:`_took_light` keeps)."""
        report = self.light_estimator.fit(lin, valid, t, rotation)
        est = self.light_estimator
        return report, (est.texel_light().copy(), float(est.spread)) if est.light is not None else None

    def _took_light(self, fitted, tm: dict, track_gain: float, defer_reference: bool) -> float:
        """A fit (:meth:`_fit_light`) taken into use on the frame's thread: its snapshot kept, the
        face relit under it for the layer and the tracker's reference; the ms waited for the main
        relight first (counted in the relight stage)."""
        self._last_light, now = fitted
        if now is None:
            return 0.0
        self._light_now = now
        waited = self._sync_relight(tm)  # the main relight first (counted as its stage)
        # The live light through the low-rank part alone (direct=0): no texel row is made for it
        # (a recipe bundle's rows cost ~35 ms each at 100k face pixels and the fitted light's
        # brightest texels change every fit). Measured on the 720p live clip against the exact
        # maps: 0.74 % relative L2 median, 0.94 % max (0.47 / 0.68 % with 8 exact texels) - within
        # the default tolerance and far below the fit's own residual (8-15 % on the real faces).
        lit = self.relighter.relight_texels(now[0], slot="live", direct=0)
        self._set_lit_reference(lit, track_gain, defer_reference)
        return waited

    def _texel_light(self) -> np.ndarray:
        """(T, 3) the live light in use, in the bundle's texels (zeros before the first)."""
        return self._light_now[0] if self._light_now is not None else self.light_estimator.texel_light()

    def _set_lit_reference(self, lit: np.ndarray, gain: float, defer: bool) -> None:
        """The tracker's reference with the face as the live light shows it (``lit``: the reference
        frame relit by the estimate, linear; ``gain``: the tracking gain of the frame the light was
        fitted to): re-anchoring then matches like with like (:func:`.tracking_image.lit_reference`).
        ``defer``: kept for :meth:`commit_reference` instead of handed to the tracker now."""
        ref = lit_reference(self.tracker.reference, lit, self.rig.lit_box, self.rig.track_face, gain)
        if defer:
            self._next_reference = ref
        else:
            self.tracker.lit_reference = ref
