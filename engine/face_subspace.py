"""The bundle's face under any light: its illumination subspace, and the reference relit as a
frame shows the face.

The bundle is linear in light: every way a light can fall on the face gives an image in the span
of a few basis images (the illumination cone: Belhumeur and Kriegman 1998; nine dimensions hold
most of a Lambertian face's, Basri and Jacobs 2003). :class:`FaceSubspace` holds that span -
the reference relit by ``BASIS_LIGHTS`` directional lights over the front hemisphere (and the
capture room's light), luminance, in linear light; its ``BASIS_DIM`` principal images inside the
face's mask. Where a frame's face is (a similarity from the face detector's keypoints), the
least-squares combination that explains it is the reference relit *as the frame is lit*
(:meth:`FaceSubspace.relit`): the template Lucas-Kanade follows into a side-lit face, which it
cannot match to the reference under the capture's light, and the share of the face's variance
it explains tells the bundle's person from another face in the frame.

Images: (H, W) float32 linear luminance; the reference's coordinates are those of the image the
basis was made in (the tracker's copy of the reference frame).
"""

from __future__ import annotations

import cv2
import numpy as np

from relight.numerics import RANK_REL, TINY_SCALE

#: Directional lights the basis is rendered under (Fibonacci directions with z above this).
BASIS_LIGHTS = 24
BASIS_MIN_Z = 0.05
#: Principal images kept (besides the constant).
BASIS_DIM = 7
#: The detector's similarity refined (:meth:`FaceSubspace.refine`): the template's face height
#: (px; at least MIN_ROWS), the rolls (degrees) and scales tried around it, and the reach of the
#: position search (a share of the face's height).
FINE_ROWS = 48
MIN_ROWS = 28
FINE_ROLL = (-6.0, -3.0, 3.0, 6.0)
FINE_SCALE = (0.92, 0.96, 1.04, 1.08)
FINE_REACH = 0.12
#: Templates kept (a face height and a roll each; rebuilt past this: ~0.1-0.2 MB each).
MAX_TEMPLATES = 64
#: Patches with less contrast than this (standard deviation over mean) are not faces (a plain
#: wall), and the floor of a window's mean (linear) in that test: flat black windows never score.
MIN_CONTRAST = 0.08
MEAN_FLOOR = 1e-4


def _point_lit(relighter, direction) -> np.ndarray:
    """The reference under one directional light for the subspace's basis. A recipe bundle's
    exact texel rows cost ~35 ms each at 100k face pixels (four a light: 3 s of start-up for the
    basis): the low-rank part alone serves a subspace of the face's images as well."""
    if relighter.row_cache is None or relighter.exact:
        return relighter.relight_light(direction)
    from relight.kernels.texel_lights import point_light

    return relighter.relight_texels(point_light(direction, relighter.map_size, relighter.texels), direct=0)


class FaceSubspace:
    """The face spanned by ``basis`` (m, h, w) float32 (reference crop whose top-left is reference
    pixel ``origin``), ``mask`` (h, w) bool the face's pixels."""

    def __init__(self, basis: np.ndarray, mask: np.ndarray, origin=(0, 0)):
        self.basis = np.asarray(basis, dtype=np.float32)
        self.mask = np.asarray(mask, dtype=bool)
        self.origin = np.asarray(origin, dtype=np.float64)
        ys, _ = np.nonzero(self.mask)
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
        if len(self._templates) >= MAX_TEMPLATES:  # (rolls around a detector's guess are any angle)
            self._templates.clear()
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

    # ------------------------------------------------------------------ refining a similarity
    def refine(self, frame: np.ndarray, sim: np.ndarray) -> tuple[np.ndarray, float] | None:
        """The reference -> frame similarity near ``sim`` (a face detector's: a few % of the face
        off) where the subspace explains ``frame`` ((H, W) float32 linear luminance) best, and
        that share: roll over FINE_ROLL, then scale over FINE_SCALE (coordinate descent), each
        over the positions within FINE_REACH of the face's height (one correlation each:
        ``cv2.matchTemplate``). None when the face's template leaves the frame."""
        frame = np.ascontiguousarray(frame, dtype=np.float32)
        m = np.asarray(sim, np.float64)
        scale = float(np.sqrt(abs(np.linalg.det(m[:, :2]))))
        if not (np.isfinite(m).all() and scale > 1e-6):
            return None
        roll = float(np.degrees(np.arctan2(m[0, 1], m[0, 0])))
        h, w = self.mask.shape
        size = self.box_h * scale
        # Padded (edges repeated) so that the template's square canvas fits around a face that
        # fills the frame or passes its edge.
        pad = int(np.ceil((0.5 * np.hypot(h, w) / self.box_h + FINE_REACH) * size * max(FINE_SCALE))) + 2
        frame = cv2.copyMakeBorder(frame, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
        cx, cy = m[:, :2] @ (self.origin + [w / 2.0, h / 2.0]) + m[:, 2] + pad
        best = self._match(frame, size, roll, cx, cy)
        if best is None:
            return None
        for dr in FINE_ROLL:
            got = self._match(frame, size, roll + dr, cx, cy)
            if got is not None and got[0] > best[0]:
                best = got
        for fs in FINE_SCALE:
            got = self._match(frame, size * fs, best[1], cx, cy)
            if got is not None and got[0] > best[0]:
                best = got
        out = best[2].copy()
        out[:, 2] -= pad  # padded -> frame coordinates
        return out, best[0]

    def _match(self, frame: np.ndarray, size: float, roll: float, cx: float, cy: float):
        """(score, roll, similarity reference -> frame) of the best position of the template of a face ``size``
        pixels high turned by ``roll`` within FINE_REACH of (cx, cy); None when out of the frame."""
        fh, fw = frame.shape
        rows = int(round(min(FINE_ROWS, max(size, MIN_ROWS))))
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
        score, _ = self._scores(small, tpl)
        _, s, _, (x, y) = cv2.minMaxLoc(score)
        # reference -> template -> resized window -> frame
        sx, sy = (x1 - x0) / ww, (y1 - y0) / wh
        t_to_f = np.array([[sx, 0.0, x * sx + x0], [0.0, sy, y * sy + y0]])
        sim = np.c_[t_to_f[:, :2] @ ref_to_t[:, :2], t_to_f[:, :2] @ ref_to_t[:, 2] + t_to_f[:, 2]]
        return float(s), roll, sim

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
