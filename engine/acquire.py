"""Finding the bundle's face in a frame under any light: matching in the face's illumination subspace.

A generic face detector (OpenCV's Haar cascade) fails on a tight crop of a face lit from one side:
half of it is black, and what is left does not look like its training faces. But the bundle *is*
this person's face, and it is linear in light: every way a light can fall on the face gives an
image in the span of a few basis images (the illumination cone: Belhumeur and Kriegman 1998; nine
dimensions hold most of a Lambertian face's, Basri and Jacobs 2003). So the face is where the
frame is best explained by that span:

* basis: the reference face relit by ``BASIS_LIGHTS`` directional lights over the front
  hemisphere (and the capture room's light), luminance, in linear light; its ``BASIS_DIM``
  principal images inside the face's mask, orthonormal and orthogonal to a constant (an offset
  the live room may add);
* score at a frame position: the share of the frame patch's variance (about its mean, inside the
  warped mask) that the basis explains - ``sum_j <B_j, f>^2 / var(f)``, 1 for a perfect fit, a
  normalised cross-correlation generalised to a subspace; every position at once from
  ``BASIS_DIM + 2`` correlations (``cv2.matchTemplate``);
* search: coarse over face sizes (``MIN_FACE`` .. ``MAX_FACE`` of the frame's height, geometric
  steps) and rolls (``ROLLS``) with the face ``COARSE_ROWS`` pixels high; the best candidates
  refined at ``FINE_ROWS`` over finer scale and roll steps.

The result is a similarity (reference -> frame) and the fitted light coefficients: the reference
relit *as the frame is lit* (:meth:`Found.relit`), the template the landmark search then follows
(instead of the reference under the capture's light, which LK cannot match to a side-lit face).

Images: (H, W) float32 linear luminance; the reference's coordinates are those of the image the
basis was made in (the tracker's copy of the reference frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from relight.numerics import RANK_REL, TINY_SCALE

#: Directional lights the basis is rendered under (Fibonacci directions with z above this).
BASIS_LIGHTS = 24
BASIS_MIN_Z = 0.05
#: Principal images kept (besides the constant).
BASIS_DIM = 7
#: Face sizes searched, as shares of the frame's height (the face's mask bounding box).
MIN_FACE = 0.15
MAX_FACE = 1.2
SCALE_STEP = 1.15
#: Rolls searched at the coarse level (degrees); the fine level searches +-FINE_ROLL around the best.
ROLLS = (-20.0, -10.0, 0.0, 10.0, 20.0)
FINE_ROLL = (-6.0, -3.0, 3.0, 6.0)
FINE_SCALE = (0.92, 0.96, 1.04, 1.08)
#: Face heights (pixels) of the coarse and the fine template.
COARSE_ROWS = 28
FINE_ROWS = 48
#: Coarse candidates refined (distinct places), and the fine search's reach around each (a share
#: of the face's height).
CANDIDATES = 6
FINE_REACH = 0.12
#: A match is accepted when the basis explains at least this share of the patch's variance.
MIN_SCORE = 0.55
#: Patches with less contrast than this (standard deviation over mean) are not faces (a plain wall).
MIN_CONTRAST = 0.08


@dataclass
class Found:
    """A face found: ``sim`` (2, 3) reference -> frame similarity, ``score`` (share of variance
    explained), ``coef`` the basis coefficients (the fitted light) and ``offset`` the patch's mean
    (the constant the live room adds, which the basis is orthogonal to)."""

    sim: np.ndarray
    score: float
    coef: np.ndarray
    offset: float


def _point_lit(relighter, direction) -> np.ndarray:
    """The reference under one directional light for the finder's basis. A recipe bundle's
    exact texel rows cost ~35 ms each at 100k face pixels (four a light: 3 s of start-up for the
    basis): the low-rank part alone serves a subspace of the face's images as well."""
    if relighter.row_cache is None or relighter.exact:
        return relighter.relight_light(direction)
    from relight.kernels.texel_lights import point_light

    return relighter.relight_texels(point_light(direction, relighter.map_size, relighter.texels), direct=0)


#: Floor of a window's mean (linear) in the contrast test: flat black windows never score.
MEAN_FLOOR = 1e-4


class FaceFinder:
    """Searches frames for the face spanned by ``basis`` (m, h, w) float32 (reference crop whose
    top-left is reference pixel ``origin``), ``mask`` (h, w) bool the face's pixels."""

    def __init__(self, basis: np.ndarray, mask: np.ndarray, origin=(0, 0)):
        self.basis = np.asarray(basis, dtype=np.float32)
        self.mask = np.asarray(mask, dtype=bool)
        self.origin = np.asarray(origin, dtype=np.float64)
        ys, xs = np.nonzero(self.mask)
        self.box_h = float(np.ptp(ys) + 1)
        self._templates: dict = {}

    @classmethod
    def from_relighter(cls, relighter, mask_full: np.ndarray, scale: float = 1.0, room: np.ndarray | None = None):
        """The basis of a bundle: its reference relit under BASIS_LIGHTS lights (and ``room``, the
        room-light image in the reference frame, when given), scaled by ``scale`` (the tracker's
        copy of the reference), cropped to ``mask_full`` (reference-frame bool mask)."""
        from relight.colour import luminance
        from relight.directions import fibonacci_sphere

        dirs = fibonacci_sphere(4 * BASIS_LIGHTS)
        dirs = dirs[dirs[:, 2] > BASIS_MIN_Z][:BASIS_LIGHTS]
        ys, xs = np.nonzero(mask_full)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        imgs = [luminance(np.array(_point_lit(relighter, d)))[y0:y1, x0:x1] for d in dirs]
        if room is not None:
            imgs.append(luminance(room)[y0:y1, x0:x1])
        stack = np.stack(imgs).astype(np.float32)
        m = mask_full[y0:y1, x0:x1]
        if scale != 1.0:
            size = (max(int(round((x1 - x0) * scale)), 8), max(int(round((y1 - y0) * scale)), 8))
            stack = np.stack([cv2.resize(s, size, interpolation=cv2.INTER_AREA) for s in stack])
            m = cv2.resize(m.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.5
        # Principal images inside the mask, the mean (a constant's share) taken out first.
        a = stack[:, m].astype(np.float64)
        a -= a.mean(axis=1, keepdims=True)
        _, sv, vt = np.linalg.svd(a, full_matrices=False)
        k = min(BASIS_DIM, int((sv > RANK_REL * max(sv[0], TINY_SCALE)).sum()))
        basis = np.zeros((k, *m.shape), np.float32)
        basis[:, m] = vt[:k]
        return cls(basis, m, origin=(x0 * scale, y0 * scale))

    # ------------------------------------------------------------------ templates
    def _template(self, rows: int, roll: float):
        """(basis (k, th, tw) orthonormal over the mask and orthogonal to it, mask (th, tw) float32,
        2x3 map reference -> template) at a face height of ``rows`` px, turned by ``roll``."""
        key = (int(rows), round(float(roll), 3))
        hit = self._templates.get(key)
        if hit is not None:
            return hit
        t0 = rows / self.box_h
        h, w = self.mask.shape
        sw, sh = max(int(round(w * t0)), 4), max(int(round(h * t0)), 4)
        sx, sy = sw / w, sh / h
        side = int(np.ceil(np.hypot(sw, sh))) + 2
        c = (side / 2.0, side / 2.0)
        rot = cv2.getRotationMatrix2D(c, float(roll), 1.0)
        # crop -> scaled (area average) -> centred on the canvas and turned
        place = rot[:, :2] @ (np.array(c) - np.array([sw, sh]) / 2.0) + rot[:, 2]
        scaled_to_t = np.c_[rot[:, :2], place]
        lin = rot[:, :2] @ np.diag([sx, sy])
        ref_to_t = np.c_[lin, place - lin @ self.origin]

        def warp(img):
            small = cv2.resize(img, (sw, sh), interpolation=cv2.INTER_AREA if t0 < 1 else cv2.INTER_LINEAR)
            return cv2.warpAffine(small, scaled_to_t, (side, side), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=0)

        m = warp(self.mask.astype(np.float32)) > 0.5
        if m.sum() < 16:
            return None
        b = np.stack([warp(x) for x in self.basis])[:, m].astype(np.float64)
        b -= b.mean(axis=1, keepdims=True)
        q, r = np.linalg.qr(b.T)
        keep = np.abs(np.diag(r)) > RANK_REL * max(float(np.abs(np.diag(r)).max()), TINY_SCALE)
        basis = np.zeros((int(keep.sum()), side, side), np.float32)
        basis[:, m] = q[:, keep].T
        out = (basis, m.astype(np.float32), ref_to_t)
        self._templates[key] = out
        return out

    @staticmethod
    def _scores(frame: np.ndarray, tpl) -> tuple[np.ndarray, np.ndarray]:
        """(score map, patch mean map) of a template over every position of ``frame``: the share
        of the patch's variance (about its mean) the face's basis explains."""
        basis, m, _ = tpl
        n = float(m.sum())
        s1 = cv2.matchTemplate(frame, m, cv2.TM_CCORR)
        s2 = cv2.matchTemplate(frame * frame, m, cv2.TM_CCORR)
        mean = s1 / n
        var = np.maximum(s2 - s1 * mean, 0.0)
        expl = np.zeros_like(var)
        for bj in basis:
            cj = cv2.matchTemplate(frame, bj, cv2.TM_CCORR)
            expl += cj * cj
        floor = n * (MIN_CONTRAST * np.maximum(mean, MEAN_FLOOR)) ** 2
        score = np.where(var > floor, expl / np.maximum(var, TINY_SCALE), 0.0)
        return score.astype(np.float32), mean

    # ------------------------------------------------------------------ search
    def find(self, frame: np.ndarray) -> Found | None:
        """The face in ``frame`` ((H, W) float32 linear luminance), or None."""
        frame = np.ascontiguousarray(frame, dtype=np.float32)
        fh, fw = frame.shape
        # Padded (edges repeated) so that a template's square canvas fits around a face that fills
        # the frame: a tight crop is the case a generic detector misses.
        aspect = np.hypot(*self.mask.shape) / self.box_h
        pad = int(np.ceil(0.5 * aspect * MAX_FACE * fh))
        frame = cv2.copyMakeBorder(frame, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
        cands = []
        size = MIN_FACE * fh
        while size <= MAX_FACE * fh:
            r = COARSE_ROWS / size
            small = cv2.resize(frame, (max(int(round((fw + 2 * pad) * r)), 1), max(int(round((fh + 2 * pad) * r)), 1)),
                               interpolation=cv2.INTER_AREA if r < 1 else cv2.INTER_LINEAR)
            for roll in ROLLS:
                tpl = self._template(COARSE_ROWS, roll)
                if tpl is None or tpl[1].shape[0] > small.shape[0] or tpl[1].shape[1] > small.shape[1]:
                    continue
                score, _ = self._scores(small, tpl)
                _, best, _, (x, y) = cv2.minMaxLoc(score)
                cands.append((best, size, roll, (x + tpl[1].shape[1] / 2.0) / r, (y + tpl[1].shape[0] / 2.0) / r))
            size *= SCALE_STEP
        if not cands:
            return None
        cands.sort(key=lambda c: -c[0])
        chosen = []
        for c in cands:  # distinct places
            if all(np.hypot(c[3] - o[3], c[4] - o[4]) > 0.25 * min(c[1], o[1]) for o in chosen):
                chosen.append(c)
            if len(chosen) == CANDIDATES:
                break
        # The largest consistent match wins: a face is similar to parts of itself at smaller
        # scales (an eye and a brow look like a small face), never to something larger.
        best, rank = None, -1.0
        for _, size, roll, cx, cy in chosen:
            got = self._refine(frame, size, roll, cx, cy)
            if got is None or got.score < MIN_SCORE:
                continue
            height = self.box_h * float(np.sqrt(abs(np.linalg.det(got.sim[:, :2]))))
            if got.score * height > rank:
                best, rank = got, got.score * height
        if best is None:
            return None
        best.sim[:, 2] -= pad  # padded -> frame coordinates
        return best

    def _refine(self, frame: np.ndarray, size: float, roll: float, cx: float, cy: float) -> Found | None:
        """A coarse match refined: roll over FINE_ROLL, then scale over FINE_SCALE (coordinate
        descent), each time over positions within FINE_REACH of the face's height."""
        best = self._match(frame, size, roll, cx, cy)
        if best is None:
            return None
        for dr in FINE_ROLL:
            got = self._match(frame, size, roll + dr, cx, cy)
            if got is not None and got[0] > best[0]:
                best = got
        roll = best[1]
        for fs in FINE_SCALE:
            got = self._match(frame, size * fs, roll, cx, cy)
            if got is not None and got[0] > best[0]:
                best = got
        return best[2]

    def _match(self, frame: np.ndarray, size: float, roll: float, cx: float, cy: float):
        """(score, roll, :class:`Found`) of the best position of the template of a face ``size``
        pixels high turned by ``roll`` within FINE_REACH of (cx, cy); None when out of the frame."""
        fh, fw = frame.shape
        rows = int(round(min(FINE_ROWS, max(size, COARSE_ROWS))))
        r = rows / size
        tpl = self._template(rows, roll)
        if tpl is None:
            return None
        basis, m, ref_to_t = tpl
        side = m.shape[0]
        half = (side / 2.0 + FINE_REACH * rows) / r
        x0, y0 = int(max(cx - half, 0)), int(max(cy - half, 0))
        x1, y1 = int(min(cx + half + 1, fw)), int(min(cy + half + 1, fh))
        ww, wh = int(round((x1 - x0) * r)), int(round((y1 - y0) * r))
        if ww < side or wh < side:
            return None
        small = cv2.resize(frame[y0:y1, x0:x1], (ww, wh), interpolation=cv2.INTER_AREA if r < 1 else cv2.INTER_LINEAR)
        score, mean = self._scores(small, tpl)
        _, s, _, (x, y) = cv2.minMaxLoc(score)
        patch = small[y:y + side, x:x + side]
        coef = np.array([float((b * patch).sum()) for b in basis])
        # reference -> template -> resized window -> frame
        sx, sy = (x1 - x0) / ww, (y1 - y0) / wh
        t_to_f = np.array([[sx, 0.0, x * sx + x0], [0.0, sy, y * sy + y0]])
        sim = np.c_[t_to_f[:, :2] @ ref_to_t[:, :2], t_to_f[:, :2] @ ref_to_t[:, 2] + t_to_f[:, 2]]
        return float(s), roll, Found(sim=sim, score=float(s), coef=coef, offset=float(mean[y, x]))

    def relit(self, frame: np.ndarray, sim: np.ndarray) -> tuple[np.ndarray, float]:
        """The reference face relit as ``frame`` ((H, W) float32 linear luminance) shows it where
        ``sim`` (reference -> frame) puts it: the least-squares combination of the constant and
        the basis images that best explains the frame's face, in the reference crop ((h, w)
        float32 linear, 0 off the mask), and the share of the face's variance it explains."""
        h, w = self.mask.shape
        # crop pixel q -> reference q + origin -> frame
        crop_to_f = np.c_[sim[:, :2], sim[:, :2] @ self.origin + sim[:, 2]]
        back = cv2.warpAffine(np.ascontiguousarray(frame, dtype=np.float32), crop_to_f, (w, h),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
        y = back[self.mask].astype(np.float64)
        a = np.c_[np.ones(y.size), self.basis[:, self.mask].T.astype(np.float64)]
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        fit = a @ coef
        var = float(((y - y.mean()) ** 2).sum())
        share = 1.0 - float(((y - fit) ** 2).sum()) / var if var > 0 else 0.0
        out = np.zeros((h, w), np.float32)
        out[self.mask] = np.maximum(fit, 0.0)
        return out, share
