"""Stage 3: light directions from the mirror sphere (paper section 3.2).

The sphere is found automatically (Hough circles on a dark frame, kept only if the flash
highlights of bright frames fall inside it), then its outline is refined to sub-pixel accuracy
from radial edge profiles of the averaged no-flash frames (a light direction is only as good as
the circle it is read from: one pixel of centre error on a 54-pixel sphere is two degrees).

In each flash frame the flash adds a small saturated highlight. The paper thresholds it at
0.85 of the maximum and takes the brightness-weighted centroid (``method="paper"``); by
default we weight the whole highlight blob (the glare around the saturated core is symmetric
and carries the sub-pixel position), and we measure what the flash *added* (flash frame minus
the no-flash average), so the room's own reflections in the ball do not pull the centroid.
Over a bright reflection of the room the flash can add less before the sensor clips, which
biases any centroid a little (measured on synthetic captures: 0.4 degrees mean with the blob,
3.3 with the paper's threshold; a Gaussian fit to the unclipped skirt was worse); frames with
no highlight, several, one at the rim, or one on a reflection that is clipped already are
dropped and counted.

The mirror law turns the highlight into a direction: orthographic by default, or with a
pinhole camera of focal length ``focal`` pixels (principal point at the image centre).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares

from relight.directions import light_for_sphere_point
from relight.numerics import EPS

#: Highlight detection, on linear luminance 0-1: the least the flash must add, the paper's
#: threshold and the blob's extent (shares of the maximum). A highlight on a reflection of the
#: room that is itself clipped (at or above SATURATED) shows nothing of the flash and is dropped.
MIN_HIGHLIGHT = 0.15
PAPER_THRESHOLD = 0.85
BLOB_THRESHOLD = 0.05
SATURATED = 0.95
#: A ball's cone (:func:`refine_cone`) is kept when its outline's edge points lie this close to it
#: (their median angular distance from the cone, as a share of its angular radius). Measured: 0.001-
#: 0.002 through 50-80 degree lenses (balls of 36 and 108 px); 0.11-0.12 where the edge search
#: missed the outline (a 100-120 degree lens stretches it past the circle's guess).
CONE_MAX_SPREAD = 0.02
#: Radial edge search for the outline refinement: relative radius range and samples per ray.
EDGE_RANGE = (0.75, 1.25)
EDGE_RAYS = 360


def find_sphere(dark_rgb: np.ndarray, bright_rgbs: list, *, exclude=None) -> tuple[float, float, float] | None:
    """(cx, cy, r) of the mirror sphere in a dark frame, or None.

    Candidates are Hough circles with radius 3-25 % of the frame height away from ``exclude``
    (the face box); the winner is the one inside which the flash's highlight appears in the
    most bright frames.
    """
    grey = cv2.GaussianBlur(cv2.cvtColor(dark_rgb, cv2.COLOR_RGB2GRAY), (0, 0), 1.5)
    h = grey.shape[0]
    circles = cv2.HoughCircles(grey, cv2.HOUGH_GRADIENT, dp=1, minDist=max(h // 10, 8), param1=60, param2=18,
                               minRadius=max(int(0.03 * h), 5), maxRadius=int(0.25 * h))
    if circles is None:
        return None
    dark = _lum(dark_rgb)
    diffs = [np.clip(_lum(b) - dark, 0, None) for b in bright_rgbs]
    yy, xx = np.mgrid[0:grey.shape[0], 0:grey.shape[1]]
    best, best_score = None, 0
    for cx, cy, r in circles[0][:12]:
        if exclude is not None:
            x, y, w, hh = exclude
            if x - r < cx < x + w + r and y - r < cy < y + hh + r:
                continue
        inside = (xx - cx) ** 2 + (yy - cy) ** 2 < (0.95 * r) ** 2
        score = 0
        for d in diffs:
            m = d[inside].max() if inside.any() else 0.0
            if m >= 0.5 and (d[inside] >= 0.5 * m).mean() < 0.05:
                score += 1
        if score > best_score:
            best, best_score = (float(cx), float(cy), float(r)), score
    return best if best_score >= 2 else None


def _lum(rgb: np.ndarray) -> np.ndarray:
    from relight.colour import decode_srgb8, luminance

    return luminance(decode_srgb8(rgb))


def refine_circle(image: np.ndarray, guess: tuple[float, float, float]) -> tuple[float, float, float]:
    """Sub-pixel outline of a sphere in ``image`` (H, W) float, starting from ``guess``.

    Along EDGE_RAYS rays from the guessed centre, the edge is the strongest brightness step
    (parabolic peak of the derivative); a circle is fitted to the edge points with a robust
    (soft L1) geometric least squares, weak edges (where ball and wall look alike) excluded.
    """
    found = _edge_points(image, guess)
    if found is None:
        return guess
    px, py = found
    cx, cy, r = guess

    def resid(p):
        return np.hypot(px - p[0], py - p[1]) - p[2]

    fit = least_squares(resid, x0=[cx, cy, r], loss="soft_l1", f_scale=0.3)
    fx, fy, fr = fit.x
    if not (np.isfinite(fit.x).all() and abs(fr - r) < 0.2 * r and np.hypot(fx - cx, fy - cy) < 0.2 * r):
        return guess
    return float(fx), float(fy), float(fr)


def _edge_points(image: np.ndarray, guess: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray] | None:
    """The outline's sub-pixel edge points (xs, ys) in ``image`` along :data:`EDGE_RAYS` rays from
    ``guess``'s centre (see :func:`refine_circle`), weak edges left out; None when fewer than 12."""
    cx, cy, r = guess
    img = np.asarray(image, dtype=np.float32)
    theta = np.linspace(0, 2 * np.pi, EDGE_RAYS, endpoint=False)
    rho = np.linspace(EDGE_RANGE[0] * r, EDGE_RANGE[1] * r, max(int(r * (EDGE_RANGE[1] - EDGE_RANGE[0]) * 10), 20))
    mx = (cx + np.cos(theta)[:, None] * rho[None, :]).astype(np.float32)
    my = (cy + np.sin(theta)[:, None] * rho[None, :]).astype(np.float32)
    prof = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    prof = ndimage.gaussian_filter1d(prof, 2.0, axis=1)
    grad = np.abs(np.gradient(prof, rho, axis=1))
    k = np.clip(np.argmax(grad, axis=1), 1, rho.size - 2)
    rows = np.arange(EDGE_RAYS)
    a, b, c = grad[rows, k - 1], grad[rows, k], grad[rows, k + 1]
    den = a - 2 * b + c
    off = np.where(np.abs(den) > EPS, 0.5 * (a - c) / np.where(np.abs(den) > EPS, den, 1.0), 0.0)
    edge = rho[k] + np.clip(off, -1, 1) * (rho[1] - rho[0])
    strength = b
    keep = strength > 0.3 * np.median(strength)
    if keep.sum() < 12:
        return None
    return cx + np.cos(theta[keep]) * edge[keep], cy + np.sin(theta[keep]) * edge[keep]


@dataclass(frozen=True)
class Cone:
    """A sphere as a pinhole sees it: the unit ray from the eye to its centre (camera space: +X
    right, +Y up, +Z toward the camera, so the ray's Z is negative) and its angular radius
    (radians). Its outline is the cone's trace on the image: a circle on the axis, an ellipse
    stretched away from it elsewhere."""

    axis: np.ndarray
    alpha: float


def _rays(xs, ys, focal: float, principal) -> np.ndarray:
    """(N, 3) unit rays from a pinhole's eye through image points (x right, y down)."""
    v = np.stack([np.asarray(xs, np.float64) - principal[0], -(np.asarray(ys, np.float64) - principal[1]),
                  np.full(np.shape(xs), -float(focal))], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def refine_cone(image: np.ndarray, guess: tuple[float, float, float], *, focal: float, principal) -> Cone | None:
    """The sphere's :class:`Cone` through a pinhole of ``focal`` pixels whose principal point is
    at ``principal`` (x, y) in ``image``'s pixels: the outline's edge points (as
    :func:`refine_circle` finds them, from ``guess``) turned into rays, and the cone that puts them
    all at one angle from its axis (robust least squares). A circle fitted in the image is the
    cone's trace only on the axis; off it, its centre and radius are not the sphere's (measured
    with a ball at 0.8 of the width through a 65-degree lens: directions 2-8 deg off with the
    circle, 0.1-0.2 with the cone). None when the outline is not found, the fit fails or its edge
    points do not lie on one cone (:data:`CONE_MAX_SPREAD`; the caller keeps the circle's
    approximation: a lens wider than ~90 degrees stretches the outline past the edge search)."""
    if not (np.isfinite(focal) and focal > 0 and guess[2] > 0):
        return None
    found = _edge_points(image, guess)
    if found is None:
        return None
    u = _rays(*found, focal, principal)
    c0 = _rays(np.array([guess[0]]), np.array([guess[1]]), focal, principal)[0]
    a0 = float(np.mean(np.arccos(np.clip(u @ c0, -1.0, 1.0))))
    # the axis as two angles about the guess's ray: c = normalise(c0 + a e1 + b e2)
    e1 = np.cross(c0, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(c0, e1)

    def axis(p):
        c = c0 + p[0] * e1 + p[1] * e2
        return c / np.linalg.norm(c)

    def resid(p):
        return np.arccos(np.clip(u @ axis(p), -1.0, 1.0)) - p[2]

    scale = max(a0, EPS) / guess[2]  # radians per pixel at the outline: soft L1 beyond ~0.3 px
    fit = least_squares(resid, x0=[0.0, 0.0, a0], loss="soft_l1", f_scale=0.3 * scale)
    c = axis(fit.x)
    spread = float(np.median(np.abs(resid(fit.x)))) / max(float(fit.x[2]), EPS)
    # as refine_circle: a fit that left its guess by a fifth of the ball is not this ball's outline
    moved = float(np.arccos(np.clip(c @ c0, -1.0, 1.0)))
    if not (fit.success and np.isfinite(fit.x).all() and 0.0 < fit.x[2] < 0.5 * np.pi
            and abs(fit.x[2] - a0) < 0.2 * a0 and moved < 0.2 * a0 and spread < CONE_MAX_SPREAD):
        return None
    return Cone(axis=c, alpha=float(fit.x[2]))


@dataclass(frozen=True)
class Highlight:
    """A flash highlight: image position (x, y) or None with the reason it was dropped."""

    xy: tuple[float, float] | None
    reason: str = ""
    peak: float = 0.0


def find_highlight(flash_lum: np.ndarray, dark_lum: np.ndarray, circle: tuple[float, float, float], *,
                   method: str = "blob") -> Highlight:
    """The flash's highlight inside ``circle`` (cx, cy, r) of linear-luminance images.

    method : 'blob' (default: brightness-weighted centroid of the whole highlight blob) or
    'paper' (centroid of the pixels above 0.85 of the maximum).
    """
    cx, cy, r = circle
    h, w = flash_lum.shape
    yy, xx = np.mgrid[0:h, 0:w]
    inside = (xx - cx) ** 2 + (yy - cy) ** 2 < (r - 1.0) ** 2
    diff = np.where(inside, np.clip(flash_lum - dark_lum, 0.0, None), 0.0)
    peak = float(diff.max())
    if peak < MIN_HIGHLIGHT:
        return Highlight(None, "no_highlight", peak)
    core = diff >= PAPER_THRESHOLD * peak
    labels, n = ndimage.label(core)
    if n > 1:
        sizes = ndimage.sum(core, labels, index=np.arange(1, n + 1))
        if np.sort(sizes)[-2] >= 0.2 * sizes.max():
            return Highlight(None, "ambiguous", peak)
    main = labels == (int(np.argmax(ndimage.sum(core, labels, index=np.arange(1, n + 1)))) + 1)
    blob_lab, _ = ndimage.label(diff >= BLOB_THRESHOLD * peak)
    blob = blob_lab == blob_lab[np.unravel_index(np.argmax(np.where(main, diff, 0)), diff.shape)]
    if _touches_rim(blob, cx, cy, r):
        return Highlight(None, "at_rim", peak)
    if dark_lum[main].max() >= SATURATED:
        return Highlight(None, "on_clipped_reflection", peak)
    sel = main if method == "paper" else blob
    wgt = diff * sel
    s = wgt.sum()
    xy = (float((xx * wgt).sum() / s), float((yy * wgt).sum() / s))
    return Highlight(xy, "", peak)


def _touches_rim(mask: np.ndarray, cx: float, cy: float, r: float) -> bool:
    ys, xs = np.nonzero(mask)
    return bool(ys.size) and float(np.hypot(xs - cx, ys - cy).max()) > r - 1.5


def light_direction(xy, circle, *, focal: float | None = None, image_size=None, cone: Cone | None = None
                    ) -> np.ndarray:
    """Unit light direction (camera space) for a highlight at image point ``xy`` on ``circle``.

    Orthographic by default; with ``focal`` (pixels) a pinhole camera with its principal point
    at the centre of an image of ``image_size`` (w, h) - the sphere its ``cone``
    (:func:`refine_cone`, the image's pixels) when given, else approximated from the circle (its
    centre's ray and radius: right on the axis only).
    """
    if focal is None:
        return light_for_sphere_point(np.asarray(xy, dtype=np.float64), circle)
    cx, cy, r = circle
    w, h = image_size
    px, py = w / 2.0, h / 2.0

    def ray(x, y):
        return _rays(np.array([x]), np.array([y]), focal, (px, py))[0]

    if cone is not None:  # the sphere's centre at distance 1 along the cone's axis
        centre, rho = np.asarray(cone.axis, np.float64), float(np.sin(cone.alpha))
    else:
        centre = ray(cx, cy)
        rho = np.sin(np.arctan2(r, np.hypot(focal, np.hypot(cx - px, cy - py)) / 1.0))
    v = ray(*xy)
    vc = v @ centre
    disc = vc * vc - 1.0 + rho * rho
    t = vc - np.sqrt(max(disc, 0.0))
    n = (t * v - centre) / rho
    n /= np.linalg.norm(n)
    to_cam = -v
    light = 2 * (n @ to_cam) * n - to_cam
    return light / np.linalg.norm(light)
