"""From an ingested video to light samples: flash separation, registration, light directions,
and the flash-only image of every flash, on the reference frame's grid.

Stages 1-3 of the paper plus what it leaves open: the ambient (no-flash) light is subtracted
from each flash frame (with the camera's exposure and white-balance drift measured on the
no-flash frames and interpolated), and the two or three frames a flash lights are averaged,
weighted by how much of their exposure it lit, into one sample per flash.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from relight.colour import luminance
from relight.errors import InputError
from relight.numerics import EPS_VALUE

from . import flash as flash_stage
from . import registration, sphere
from .ingest import Ingested

#: Frames a flash lit for at least this share of its peak are averaged into its sample.
SAMPLE_LEVEL = 0.85
#: Pixels with a channel at or above this share of the code range's top count as clipped (the
#: sample is flagged there): code 250 of 8-bit video, the same share of the signal in 10-bit/HDR.
CLIP_LEVEL = 250.0 / 255.0
#: A flash sample adding less than this share of the median sample's light to the face is dropped.
WEAK_SHARE = 0.1
#: No-flash frames averaged into the room light, and the pixel step of the exposure measurement.
AMBIENT_FRAMES = 120
GAIN_STEP = 4


@dataclass
class SampleOptions:
    """Switches and parameters of stages 1-3 (each switchable so its effect can be measured)."""

    flash_hz: float | None = None
    flash_threshold: float = flash_stage.DEFAULT_THRESHOLD
    flash_min_share: float = flash_stage.DEFAULT_MIN_SHARE
    sphere: tuple[float, float, float] | None = None
    #: The capture's camera for the sphere: "auto" (its focal length found from the ball's outline:
    #: :func:`.sphere.find_focal`), a focal length in pixels of the video's frames, or None (orthographic).
    focal: float | str | None = "auto"
    highlight: str = "blob"
    register: bool = True
    subtract_ambient: bool = True
    refine_sphere: bool = True


@dataclass
class Samples:
    """Light samples on the reference grid (the stored crop of the reference frame).

    images : (K, h, w, 3) float32 linear flash-only images, one per flash (K flashes kept).
    dirs : (K, 3) unit light directions (camera space). clipped : (K, h, w) bool.
    ambient : (h, w, 3) float32 linear no-flash average (registered). reference : (h, w, 3)
    uint8 sRGB reference frame crop. origin : (x, y) of the crop in the frame.
    """

    images: np.ndarray
    dirs: np.ndarray
    clipped: np.ndarray
    ambient: np.ndarray
    reference: np.ndarray
    origin: tuple[int, int]
    frame_size: tuple[int, int]
    reference_frame: int
    flash: flash_stage.FlashFrames
    motions: dict
    motion_center: tuple[float, float]
    circle: tuple[float, float, float] | None
    light_dirs: dict
    pulse_frames: list
    rejected: dict = field(default_factory=dict)
    #: The camera the light directions were read with (:func:`sphere_camera`).
    camera: dict = field(default_factory=lambda: {"focal_px": None, "source": "orthographic"})
    timings: dict = field(default_factory=dict)
    track_quality: dict = field(default_factory=dict)


def _face_region(ing: Ingested) -> np.ndarray:
    """Boolean mask (crop coordinates) where registration features are taken: the face box,
    or the whole crop outside the sphere when there is no face."""
    h, w = ing.crop_shape
    region = np.zeros((h, w), dtype=bool)
    if ing.face_box is not None:
        x, y, fw, fh = ing.face_box
        x0, y0 = x - ing.crop[0], y - ing.crop[1]
        cv2.ellipse(region.view(np.uint8), (int(x0 + fw / 2), int(y0 + fh / 2)), (int(fw * 0.45), int(fh * 0.55)),
                    0, 0, 360, 1, -1)
    else:
        region[:] = True
        if ing.sphere_guess is not None:
            cx, cy, r = ing.sphere_guess
            cv2.circle(region.view(np.uint8), (int(cx - ing.crop[0]), int(cy - ing.crop[1])), int(r * 1.5), 0, -1)
    return region


def _one_per_run(frames) -> list[int]:
    """The middle frame of each run of consecutive frame numbers."""
    frames = [int(f) for f in frames]
    out, run = [], []
    for f in frames:
        if run and f != run[-1] + 1:
            out.append(run[len(run) // 2])
            run = []
        run.append(f)
    if run:
        out.append(run[len(run) // 2])
    return out


def collect_samples(ing: Ingested, opts: SampleOptions | None = None, *,
                    progress: Callable[[str, int, int], None] | None = None) -> Samples:
    """Stages 1-3 on an ingested capture (see the module docstring). Consumes ``ing.crops``: the
    crops it no longer needs are set to None as it goes (all but the reference's at the end)."""
    opts = opts or SampleOptions()
    timings: dict[str, float] = {}
    rejected: dict[str, int] = {}
    t0 = time.perf_counter()
    fl = flash_stage.separate(ing.face_trace(), ing.fps, opts.flash_hz, opts.flash_threshold, opts.flash_min_share,
                              times=ing.times)
    rejected.update({f"flash_{k}": v for k, v in fl.rejected.items() if v})
    timings["flash"] = time.perf_counter() - t0

    # ---- registration on the no-flash frames
    t0 = time.perf_counter()
    ref = int(fl.dark[0])
    x0, y0 = ing.crop[:2]
    center = _motion_center(ing)
    center_crop = (center[0] - x0, center[1] - y0)
    motions: dict[int, tuple[float, float, float]] = {ref: (0.0, 0.0, 0.0)}
    quality = {}
    if opts.register:
        motions, quality = _track_no_flash(ing, fl.dark, ref, center_crop, rejected, progress)
    all_motions = registration.interpolate_motions(motions, range(ing.frame_count), ing.times)
    timings["registration"] = time.perf_counter() - t0

    # ---- ambient: registered no-flash average and each no-flash frame's exposure/white balance
    t0 = time.perf_counter()
    dark_used = [int(d) for d in fl.dark if int(d) in motions]
    ambient = _ambient_image(ing, dark_used, opts.register, all_motions, center_crop)
    region = _face_region(ing)
    gains = _exposure_gains(ing, ambient, region, dark_used)
    # From here on only the flash frames' crops (and the reference's) are read: the others are
    # let go (memory: a crop per frame of a long 1080p capture is about a gigabyte).
    _release_crops(ing, {int(f) for f in fl.flash_frames} | {ref})
    drift = _ExposureDrift.from_gains(gains, ing)
    timings["ambient"] = time.perf_counter() - t0

    # ---- sphere: outline, highlights -> light directions per flash frame
    t0 = time.perf_counter()
    circle, camera, light_dirs = _light_directions(ing, opts, fl, dark_used, drift, rejected)
    timings["sphere"] = time.perf_counter() - t0

    # ---- one sample per flash: its well-lit frames, registered, ambient removed, level-weighted
    t0 = time.perf_counter()
    sampler = _PulseSampler(ing=ing, opts=opts, level=fl.level, light_dirs=light_dirs, ref=ref, drift=drift,
                            motions=all_motions, center=center_crop, ambient=ambient)
    images, clipped, dirs, pulse_frames = _flash_samples(sampler, _frames_by_pulse(fl, light_dirs), progress)
    images, clipped, dirs, pulse_frames = _drop_weak(images, clipped, dirs, pulse_frames, region, rejected)
    if len(images) < 4:
        raise InputError(f"only {len(images)} usable flash samples (need at least 4); see the rejected counts: "
                         + ", ".join(f"{k} {v}" for k, v in rejected.items()))
    timings["samples"] = time.perf_counter() - t0
    return Samples(images=images, dirs=np.stack(dirs), clipped=clipped, ambient=ambient,
                   reference=ing.crops[ref].rgb(), origin=(x0, y0), frame_size=ing.size, reference_frame=ref,
                   flash=fl, motions=all_motions, motion_center=center, circle=circle,
                   light_dirs={int(f): d for f, d in light_dirs.items()}, pulse_frames=pulse_frames,
                   rejected=rejected, timings=timings, track_quality=quality, camera=camera)


def _motion_center(ing: Ingested) -> tuple[float, float]:
    """The point (x, y) in frame pixels the head's motion turns about: the face box's centre, or the crop's."""
    x0, y0 = ing.crop[:2]
    if ing.face_box is not None:
        fx, fy, fw, fh = ing.face_box
        return (fx + fw / 2.0, fy + fh / 2.0)
    return (x0 + ing.crop[2] / 2.0, y0 + ing.crop[3] / 2.0)


def _track_no_flash(ing: Ingested, dark: np.ndarray, ref: int, center_crop, rejected: dict,
                    progress) -> tuple[dict, dict]:
    """Track the face on one no-flash frame per run: frame -> motion (relative to ``ref``, about
    ``center_crop``) and frame -> (inliers, residual); lost frames are counted in ``rejected``."""
    motions: dict[int, tuple[float, float, float]] = {ref: (0.0, 0.0, 0.0)}
    quality = {}
    try:
        tracker = registration.Tracker(ing.crops[ref].luma(native=True), _face_region(ing))
    except ValueError as exc:
        raise InputError(f"registration failed: {exc}; give --face x,y,w,h around the face") from None
    tracked = _one_per_run(dark[1:])
    for i, d in enumerate(tracked):
        res = tracker.track(ing.crops[int(d)].luma(native=True))
        if np.isfinite(res.residual):
            motions[int(d)] = registration.matrix_to_motion(res.matrix, center_crop)
            quality[int(d)] = (res.inliers, res.residual)
        else:
            rejected["track_lost"] = rejected.get("track_lost", 0) + 1
        if progress:
            progress("register", i + 1, len(tracked))
    return motions, quality


def _ambient_image(ing: Ingested, dark_used: list[int], register: bool, all_motions: dict,
                   center_crop) -> np.ndarray:
    """The room light: (h, w, 3) float32 linear average of up to AMBIENT_FRAMES no-flash frames,
    registered to the reference when ``register``."""
    h, w = ing.crop_shape
    amb_sum = np.zeros((h, w, 3), dtype=np.float64)
    # The room light's average needs no more than AMBIENT_FRAMES frames (sensor noise falls as
    # 1/sqrt(n)); each frame's exposure and white balance are measured on all of them, sparsely.
    pick = dark_used if len(dark_used) <= AMBIENT_FRAMES else \
        [dark_used[int(i)] for i in np.linspace(0, len(dark_used) - 1, AMBIENT_FRAMES)]
    for d in pick:
        img = ing.crops[d].linear()
        if register:
            img = registration.warp_to_reference(img, all_motions[d], center_crop, interpolation=cv2.INTER_LINEAR)
        amb_sum += img
    return (amb_sum / len(pick)).astype(np.float32)


def _exposure_gains(ing: Ingested, ambient: np.ndarray, region: np.ndarray, dark_used: list[int]) -> dict:
    """Frame -> (3,) gain of each no-flash frame over the ambient image, measured on the lit face
    (every GAIN_STEP-th pixel): the camera's exposure and white balance."""
    core = region & (luminance(ambient) > 0.01)
    if not core.any():
        core = luminance(ambient) > 0.005
    core_s = core[::GAIN_STEP, ::GAIN_STEP]
    amb_mean = ambient[::GAIN_STEP, ::GAIN_STEP][core_s].mean(axis=0) + EPS_VALUE
    return {d: ing.crops[d].sparse(GAIN_STEP).linear()[core_s].mean(axis=0) / amb_mean for d in dark_used}


def _release_crops(ing: Ingested, needed: set[int]) -> None:
    """Set every crop not in ``needed`` to None (frees its memory)."""
    for i in range(len(ing.crops)):
        if i not in needed:
            ing.crops[i] = None


@dataclass
class _ExposureDrift:
    """The camera's exposure and white balance over time, measured on no-flash frames.

    times : (N,) each frame's time in seconds (frame numbers when the video has none).
    frames : (D,) the measured frames. gains : (D, 3) their gains over the ambient image.
    """

    times: np.ndarray
    frames: np.ndarray
    gains: np.ndarray

    @classmethod
    def from_gains(cls, gains: dict, ing: Ingested) -> _ExposureDrift:
        """From frame -> (3,) gain, on the capture's frame times."""
        gidx = np.array(sorted(gains), dtype=np.int64)
        gval = np.array([gains[int(i)] for i in gidx])
        times = ing.times if ing.times is not None else np.arange(ing.frame_count, dtype=np.float64)
        return cls(times=times, frames=gidx, gains=gval)

    def at(self, f) -> np.ndarray:
        """(3,) float32 gain of frame ``f``: exposure and white balance drift in time, interpolated in time."""
        return np.array([np.interp(self.times[f], self.times[self.frames], self.gains[:, c]) for c in range(3)],
                        dtype=np.float32)


def _light_directions(ing: Ingested, opts: SampleOptions, fl: flash_stage.FlashFrames, dark_used: list[int],
                      drift: _ExposureDrift, rejected: dict) -> tuple[tuple, dict, dict]:
    """The sphere's circle (frame pixels), the camera (:func:`sphere_camera`) and frame -> (3,) unit
    light direction of each well-lit flash frame whose highlight was found (misses counted in ``rejected``)."""
    circle = ing.sphere_guess  # given (--sphere) or found, in the working frame (ingest scaled it)
    light_dirs: dict[int, np.ndarray] = {}
    if circle is None or ing.sphere_crops is None:
        raise InputError("no mirror sphere found; give --sphere cx,cy,r (centre and radius in pixels)")
    sx0, sy0 = ing.sphere_box[:2]
    dark_sphere = np.mean([luminance(ing.sphere_crops[d].linear()) for d in dark_used], axis=0)
    local = (circle[0] - sx0, circle[1] - sy0, circle[2])
    if opts.refine_sphere:
        local = sphere.refine_circle(dark_sphere, local)
    circle = (local[0] + sx0, local[1] + sy0, local[2])
    principal = (ing.size[0] / 2 - sx0, ing.size[1] / 2 - sy0)
    camera = sphere_camera(opts, ing.scale, ing.size, dark_sphere, local, principal)
    focal = None if camera["focal_px"] is None else camera["focal_px"] * ing.scale  # px of the working frame
    # Through a pinhole the ball is a cone of rays: its outline's centre and radius are not the
    # ball's off the axis (sphere.refine_cone; the circle's approximation when it is not found).
    cone = None if focal is None or not opts.refine_sphere else \
        sphere.refine_cone(dark_sphere, local, focal=focal, principal=principal)
    for f in fl.flash_frames:
        f = int(f)
        if fl.level[f] < SAMPLE_LEVEL:
            continue
        lum = luminance(ing.sphere_crops[f].linear()) / float(drift.at(f).mean())
        hl = sphere.find_highlight(lum, dark_sphere, local, method=opts.highlight)
        if hl.xy is None:
            rejected[f"highlight_{hl.reason}"] = rejected.get(f"highlight_{hl.reason}", 0) + 1
            continue
        xy = (hl.xy[0] + sx0, hl.xy[1] + sy0)
        light_dirs[f] = sphere.light_direction(xy, circle, focal=focal, image_size=ing.size, cone=cone)
    return circle, camera, light_dirs


def _frames_by_pulse(fl: flash_stage.FlashFrames, light_dirs: dict) -> dict[int, list[int]]:
    """Flash index -> its frames lit for at least SAMPLE_LEVEL of its peak and with a light direction."""
    by_pulse: dict[int, list[int]] = {}
    for f, k in fl.pulse_of.items():
        if fl.level[f] >= SAMPLE_LEVEL and f in light_dirs:
            by_pulse.setdefault(k, []).append(int(f))
    return by_pulse


@dataclass
class _PulseSampler:
    """Turns the frames one flash lit into its flash-only image on the reference grid.

    level : (N,) each frame's share of its flash. motions : frame -> motion about ``center``
    (crop pixels). ambient : (h, w, 3) float32 linear room light.
    """

    ing: Ingested
    opts: SampleOptions
    level: np.ndarray
    light_dirs: dict
    ref: int
    drift: _ExposureDrift
    motions: dict
    center: tuple[float, float]
    ambient: np.ndarray

    def sample(self, frames: list[int], out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Write the flash's image, (h, w, 3) float32 linear, into ``out``; returns its clipped
        mask (h, w) bool and the sum (3,) of its frames' light directions."""
        # The frames of one flash are a few milliseconds apart: the head moved by hundredths of
        # a pixel between them, so they are summed first and warped once, with their mean motion
        # and exposure.
        h, w = self.ing.crop_shape
        acc = np.zeros((h, w, 3), dtype=np.float32)
        clip = np.zeros((h, w), dtype=bool)
        wsum = 0.0
        dsum = np.zeros(3)
        for f in frames:
            lin, clipped_f = self.ing.crops[f].linear_and_clipped(CLIP_LEVEL)
            acc += lin
            wsum += float(self.level[f])
            clip |= clipped_f
            if f != self.ref:
                self.ing.crops[f] = None  # used once
            dsum += self.light_dirs[f]
        gain = np.mean([self.drift.at(f) for f in frames], axis=0)
        img = acc / (gain * len(frames))  # mean frame at the reference exposure
        if self.opts.register:
            mot = tuple(np.mean([self.motions[f] for f in frames], axis=0))
            img = registration.warp_to_reference(img, mot, self.center)
            clip = registration.warp_to_reference(clip.astype(np.uint8), mot, self.center,
                                                  interpolation=cv2.INTER_NEAREST) > 0
        if self.opts.subtract_ambient:
            img = img - self.ambient
        # Each frame showed its share `level` of the flash: scale the mean to a full flash.
        np.multiply(img, len(frames) / max(wsum, EPS_VALUE), out=out)
        return clip, dsum


def _flash_samples(sampler: _PulseSampler, by_pulse: dict[int, list[int]], progress):
    """One sample per flash, in flash order: images (K, h, w, 3) float32, clipped (K, h, w) bool,
    unit light directions (K of (3,)) and each sample's frames."""
    h, w = sampler.ing.crop_shape
    # Filled in place: a list of images then a stacked copy would need twice the memory.
    images = np.empty((len(by_pulse), h, w, 3), dtype=np.float32)
    clipped = np.empty((len(by_pulse), h, w), dtype=bool)
    dirs, pulse_frames = [], []
    for n_done, (_, frames) in enumerate(sorted(by_pulse.items())):
        clip, dsum = sampler.sample(frames, images[n_done])
        clipped[n_done] = clip
        dirs.append(dsum / np.linalg.norm(dsum))
        pulse_frames.append(frames)
        if progress:
            progress("samples", n_done + 1, len(by_pulse))
    return images, clipped, dirs, pulse_frames


def _drop_weak(images, clipped, dirs, pulse_frames, region: np.ndarray, rejected: dict):
    """Drop the samples adding under WEAK_SHARE of the median sample's light on the face (counted in ``rejected``)."""
    # A flash whose light barely reached the face (ill-aimed) would paint a dark patch into the
    # maps: drop samples adding under WEAK_SHARE of the median sample's light on the face.
    if len(images):
        face_light = np.array([luminance(im[region]).mean() for im in images])
        weak = face_light < WEAK_SHARE * float(np.median(face_light))
        if weak.any():
            rejected["weak_flash"] = int(weak.sum())
            keep = np.flatnonzero(~weak)
            images, clipped = images[keep], clipped[keep]
            dirs = [dirs[i] for i in keep]
            pulse_frames = [pulse_frames[i] for i in keep]
    return images, clipped, dirs, pulse_frames


def sphere_camera(opts: SampleOptions, scale: float, size: tuple[int, int], dark_sphere: np.ndarray, local, principal
                  ) -> dict:
    """The capture's camera as the sphere's directions take it (the report's ``camera``):
    ``focal_px`` in pixels of the video's frames (the working frame's, of ``size``, are the
    video's times ``scale``) or None (orthographic), and ``source``: "told" (``opts.focal``),
    "orthographic" (told None) or "sphere" (``"auto"``: :func:`.sphere.find_focal` on the
    averaged no-flash ball ``dark_sphere`` around the circle ``local``, the principal point
    ``principal`` in its pixels, with the outline's misfits in the working frame's pixels; None
    when the outline says nothing of it)."""
    f = opts.focal
    if f is None:
        return {"focal_px": None, "source": "orthographic"}
    if isinstance(f, str):
        if f != "auto":
            raise InputError(f"focal {f!r}: give a focal length in pixels, 'auto' or None (orthographic)")
        if not opts.refine_sphere:
            return {"focal_px": None, "source": "sphere", "note": "the ball's outline is not refined: no focal length"}
        found = sphere.find_focal(dark_sphere, local, principal=principal, size=size)
        if found is None:
            return {"focal_px": None, "source": "sphere", "note": "the ball's outline was not found"}
        return {"focal_px": None if found.focal is None else found.focal / scale, "source": "sphere",
                "outline_misfit_px": round(found.misfit_px, 4),
                "orthographic_misfit_px": round(found.orthographic_misfit_px, 4)}
    if not (np.isfinite(f) and f > 0):
        raise InputError(f"focal {f}: give a positive focal length in pixels")
    return {"focal_px": float(f), "source": "told"}
