"""Accuracy of a capture against the synthetic studio's truth (used by tests and benchmarks).

Measures, for a capture of a ``relight synth`` video:

* flash frames: precision and recall of the frames found against ``flash_frames``;
* registration: RMS displacement error (pixels) over the head's pixels, every frame, of the
  estimated motion against the truth's (both relative to the capture's reference frame);
* light directions: angular error (degrees) per flash frame with a direction;
* normals: angular error (degrees) inside both the estimated and the true masks;
* mask: intersection over union with the truth's.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

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
    c_true = meta["head_center"]
    ref = int(report["reference_frame"])
    t_ref_inv = np.linalg.inv(_h(rigid_matrix(*meta["head_motion"][ref], c_true)))
    c_est = np.asarray(report["transform_center"], dtype=np.float64) / s
    errs = []
    for f, mot in report["transforms"].items():
        true = _h(rigid_matrix(*meta["head_motion"][int(f)], c_true)) @ t_ref_inv
        est = _h(rigid_matrix(mot[0] / s, mot[1] / s, mot[2], c_est))
        d = (pts @ true.T - pts @ est.T)[:, :2]
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
    return out
