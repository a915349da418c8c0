"""Accuracy of a capture against the synthetic studio's truth (used by tests and benchmarks).

Measures, for a capture of a ``relight synth`` video:

* flash frames: precision and recall of the frames found against ``flash_frames``;
* registration: RMS displacement error (pixels) over the head's pixels, every frame, of the
  estimated motion against the truth's (both relative to the capture's reference frame);
* light directions: angular error (degrees) per flash frame with a direction;
* normals: angular error (degrees) inside both the estimated and the true masks;
* mask: intersection over union with the truth's;
* relit: PSNR (dB, peak the truth's brightest face pixel) of the bundle relit under each truth
  environment of :data:`RELIT_ENVS` (the default compact path, what users get) against the
  truth's render, over the face, after one least-squares gain and a sub-pixel alignment
  (:func:`relit_psnr`).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from relight.colour import LUMINANCE
from relight.directions import angle_between_deg, rigid_matrix
from relight.imageio import read_image
from relight.numerics import EPS_VALUE

from .flash import precision_recall


def _h(m):
    return np.vstack([m, [0.0, 0.0, 1.0]])


def evaluate_capture(report: dict, bundle, truth_dir) -> dict:
    """Metrics of a capture (its report dict and loaded bundle) against ``truth_dir``."""
    truth_dir = Path(truth_dir)
    meta = json.loads((truth_dir / "meta.json").read_text())
    out: dict = {}
    p, r = precision_recall(report["flash_frames"], meta["flash_frames"])
    out["flash_precision"], out["flash_recall"] = p, r
    mask = cv2.imread(str(truth_dir / "mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    # A capture downscaled for --face-pixels works in a smaller frame: its motions are brought to
    # the truth's pixels, the truth's images down to its frame.
    s = float(bundle.meta.get("capture_scale", 1.0))
    ys, xs = np.nonzero(mask)
    pts = np.stack([xs, ys, np.ones(xs.size)], axis=1)[:: max(xs.size // 2000, 1)]
    ref = int(report["reference_frame"])
    at_ref, moved = _true_motion(meta, pts, truth_dir, ref)
    c_est = np.asarray(report["transform_center"], dtype=np.float64) / s
    errs = []
    for f, mot in report["transforms"].items():
        est = _h(rigid_matrix(mot[0] / s, mot[1] / s, mot[2], c_est))
        d = moved(int(f)) - (at_ref @ est.T)[:, :2]
        errs.append(np.mean(np.sum(d * d, axis=1)))
    out["registration_rms_px"] = float(np.sqrt(np.mean(errs)))
    ang = [float(angle_between_deg(d, meta["light_dirs"][f])) for f, d in report["light_dirs"].items()
           if f in meta["light_dirs"]]
    ang = np.asarray(ang)
    out["light_dir_mean_deg"] = float(ang.mean()) if ang.size else float("nan")
    out["light_dir_p95_deg"] = float(np.percentile(ang, 95)) if ang.size else float("nan")
    out["light_dir_count"] = int(ang.size)
    n_true = read_image(truth_dir / "normals.exr")
    if s != 1.0:
        size = bundle.frame_size
        mask = cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.5
        n_true = cv2.resize(n_true, size, interpolation=cv2.INTER_AREA)
        n_true /= np.maximum(np.linalg.norm(n_true, axis=-1, keepdims=True), EPS_VALUE)
    x0, y0 = bundle.crop_origin
    m_est = np.asarray(bundle.mask_crop)
    h, w = m_est.shape
    m_true = mask[y0:y0 + h, x0:x0 + w]
    both = m_est & m_true
    out["mask_iou"] = float(both.sum() / max((m_est | m_true).sum(), 1))
    n_true = n_true[y0:y0 + h, x0:x0 + w]
    n_est = np.zeros((h * w, 3), dtype=np.float32)
    n_est[np.asarray(bundle.pixels)] = np.asarray(bundle.normal)
    n_est = n_est.reshape(h, w, 3)
    a = angle_between_deg(n_est[both], n_true[both])
    out["normal_median_deg"] = float(np.median(a)) if a.size else float("nan")
    out["normal_p90_deg"] = float(np.percentile(a, 90)) if a.size else float("nan")
    relit = meta.get("files", {}).get("relit", {})
    for env in RELIT_ENVS:
        if env in relit:
            out[f"relit_psnr_{env}"] = relit_psnr(bundle, truth_dir.parent / relit[env], f"builtin:{env}",
                                                  truth_dir / "mask.png")
    return out


def _true_motion(meta: dict, pts: np.ndarray, truth_dir: Path, ref: int):
    """Points of the head in the capture's reference frame ``ref`` and where they are at any
    frame: ((N, 3) homogeneous image points, a function of the frame returning (N, 2)), from the
    truth's reference pixels ``pts`` (N, 3: column, row, 1). Orthographic: ``pts`` taken as the
    reference frame's, moved by the frames' image-plane motions (``head_motion`` about
    ``head_center``) relative to its. Through a pinhole (``camera``): each pixel lifted to its
    surface point (``depth.exr``: its height), moved in space by each frame's roll and shift
    about ``pivot`` and projected - a face's parts move by their own depth's scale."""
    cam = meta.get("camera", {"model": "orthographic"})
    if cam["model"] != "pinhole":
        c_true = meta["head_center"]
        t_ref_inv = np.linalg.inv(_h(rigid_matrix(*meta["head_motion"][ref], c_true)))
        return pts, lambda f: (pts @ (_h(rigid_matrix(*meta["head_motion"][f], c_true)) @ t_ref_inv).T)[:, :2]
    from .synth.pinhole import Pinhole
    from .synth.pinhole_view import motion_pose

    camera = Pinhole(focal=float(cam["focal_px"]), center=tuple(cam["principal_point"]), eye_z=float(cam["eye_z"]),
                     fov_deg=float(cam["fov_deg"]), distance_cm=float(cam["distance_cm"]),
                     distance_px=float(cam["distance_px"]))
    (cx, cy), eye_z = camera.center, camera.eye_z
    height = read_image(truth_dir / "depth.exr")
    height = height[..., 0] if height.ndim == 3 else height
    z = height[pts[:, 1].astype(int), pts[:, 0].astype(int)].astype(np.float64)
    scale = (eye_z - z) / camera.focal  # camera-space units a pixel at that depth (image_points inverted)
    points = np.stack([cx + (pts[:, 0] - cx) * scale, -(cy + (pts[:, 1] - cy) * scale), z], axis=1)
    pivot = np.array([meta["pivot"][0], -meta["pivot"][1], meta["pivot"][2]], dtype=np.float64)

    def at(f: int) -> np.ndarray:
        r, (tx, ty) = motion_pose(meta["head_motion"][f])
        return np.stack(camera.image_points((points - pivot) @ r.T + pivot + np.array([tx, -ty, 0.0])), axis=1)

    return np.concatenate([at(ref), np.ones((len(pts), 1))], axis=1), at


#: The truth environments a capture's relit result is measured under (a broad and a low sun).
RELIT_ENVS = ("window", "sunset")
#: Largest shift (pixels) the relit result is aligned by: the capture's reference frame is a
#: frame of the clip, the truth's head at rest - they differ by the head's small motion.
ALIGN_MAX_PX = 3.0


def relit_psnr(bundle, truth_file, env: str, mask_file) -> float:
    """PSNR (dB) of ``bundle`` relit under ``env`` (its default compact path) against the truth
    render ``truth_file`` over the face (the bundle's and the truth's masks), after a sub-pixel
    shift (phase correlation of the two over the face, within :data:`ALIGN_MAX_PX`) and one
    least-squares gain (the capture's units are its flash's). Peak: the truth's brightest face
    pixel. Downscaled bundles are compared with the truth brought to their frame."""
    from relight.envmap import load_environment
    from relight.kernels.relighter import Relighter

    pred = Relighter(bundle).relight(load_environment(env)).astype(np.float64)
    truth = read_image(truth_file).astype(np.float64)
    tmask = cv2.imread(str(mask_file), cv2.IMREAD_GRAYSCALE) > 0
    size = (pred.shape[1], pred.shape[0])
    if truth.shape[:2] != pred.shape[:2]:
        truth = cv2.resize(truth, size, interpolation=cv2.INTER_AREA)
        tmask = cv2.resize(tmask.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.5
    face = np.asarray(bundle.mask) & tmask
    lum = LUMINANCE.astype(np.float64)
    window = cv2.createHanningWindow(size, cv2.CV_64F)
    (dx, dy), _ = cv2.phaseCorrelate(np.where(face, truth @ lum, 0.0), np.where(face, pred @ lum, 0.0), window)
    if np.hypot(dx, dy) > ALIGN_MAX_PX:
        dx = dy = 0.0
    shift = np.float32([[1, 0, -dx], [0, 1, -dy]])
    pred = cv2.warpAffine(pred, shift, size, flags=cv2.INTER_LINEAR)
    inside = cv2.warpAffine(np.asarray(bundle.mask, np.float32), shift, size, flags=cv2.INTER_LINEAR) > 0.999
    sel = inside & tmask
    a, b = pred[sel], truth[sel]
    gain = float((a * b).sum() / max(float((a * a).sum()), EPS_VALUE))
    mse = float(np.mean((gain * a - b) ** 2))
    return float(10.0 * np.log10(float(b.max()) ** 2 / max(mse, 1e-30)))
