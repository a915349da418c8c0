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
#: ``--focal auto`` (:func:`find_focal`): focal lengths tried, times the frame's larger side (a
#: 118-degree lens to a 7-degree one), how many (evenly in log), and the share of the orthographic
#: circle's outline misfit the best cone must reach to be kept. Measured on the studio's ball at
#: 0.8 of a 640x360 frame's width: misfits 0.09-0.10 px at the true focal length of 50, 65 and 80
#: degree lenses against 0.54-1.80 px for the circle (0.17-0.05 of it); through an orthographic
#: camera the misfit falls toward the circle's as the focal length grows (no minimum).
FOCAL_RANGE = (0.3, 8.0)
FOCAL_STEPS = 29
FOCAL_MIN_GAIN = 0.5
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
    fit = _fit_cone(found, focal, principal, guess)
    return None if fit is None or fit[1] >= CONE_MAX_SPREAD else fit[0]


def _fit_cone(points, focal: float, principal, guess) -> tuple[Cone, float, float] | None:
    """The :class:`Cone` through a pinhole of ``focal`` px whose edge rays (from image ``points``
    (xs, ys)) lie closest to it (robust least squares from ``guess``'s circle), its spread (the
    edge rays' median angular distance from it over its angular radius) and that distance in
    pixels of the outline; None when the fit fails or leaves its guess by a fifth of the ball."""
    u = _rays(*points, focal, principal)
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
    alpha = float(fit.x[2])
    off = float(np.median(np.abs(resid(fit.x))))
    # as refine_circle: a fit that left its guess by a fifth of the ball is not this ball's outline
    moved = float(np.arccos(np.clip(c @ c0, -1.0, 1.0)))
    if not (fit.success and np.isfinite(fit.x).all() and 0.0 < alpha < 0.5 * np.pi
            and abs(alpha - a0) < 0.2 * a0 and moved < 0.2 * a0):
        return None
    return Cone(axis=c, alpha=alpha), off / alpha, off / alpha * guess[2]


def _circle_misfit(points, guess) -> float:
    """The edge points' median distance (px) from their robust circle: the orthographic ball's
    outline misfit (the cone's as the focal length grows without bound)."""
    px, py = points

    def resid(p):
        return np.hypot(px - p[0], py - p[1]) - p[2]

    fit = least_squares(resid, x0=list(guess), loss="soft_l1", f_scale=0.3)
    return float(np.median(np.abs(resid(fit.x))))


@dataclass(frozen=True)
class FocalFound:
    """What :func:`find_focal` read from a ball's outline: the focal length (px of the image; None:
    the orthographic camera explains it as well) and the outline's misfit (px, the edge points'
    median distance) at it and with the orthographic camera's circle."""

    focal: float | None
    misfit_px: float
    orthographic_misfit_px: float


def find_focal(image: np.ndarray, guess: tuple[float, float, float], *, principal, size: tuple[int, int]
               ) -> FocalFound | None:
    """The camera's focal length from the ball's outline, when not told (``relight capture``'s
    ``--focal auto``). Through a pinhole a ball off the axis is an ellipse stretched toward the
    principal point (``principal``, (x, y) in ``image``'s pixels) by an amount the focal length
    sets; only the right focal length puts all the outline's edge rays on one cone. So each focal
    length of :data:`FOCAL_RANGE` x the frame's larger side (``size`` (w, h)), :data:`FOCAL_STEPS`
    of them spaced evenly in log, is scored by the edge points' distance from their best cone
    (:func:`_fit_cone`), the lowest refined by a parabola through it and its neighbours in log
    focal length; it is kept when its misfit is at most :data:`FOCAL_MIN_GAIN` of the orthographic
    camera's (a ball near the axis, or an orthographic view, says nothing of the focal length:
    then None). None when the outline is not found."""
    if not guess[2] > 0:
        return None
    found = _edge_points(image, guess)
    if found is None:
        return None
    ortho = _circle_misfit(found, guess)
    focals = max(size) * np.geomspace(*FOCAL_RANGE, FOCAL_STEPS)
    misfit = np.full(focals.size, np.inf)
    for i, f in enumerate(focals):
        fit = _fit_cone(found, float(f), principal, guess)
        if fit is not None:
            misfit[i] = fit[2]
    i = int(np.argmin(misfit))
    if not np.isfinite(misfit[i]) or i == focals.size - 1:
        return FocalFound(None, ortho, ortho)
    best, f_best = float(misfit[i]), float(focals[i])
    if 0 < i and np.isfinite(misfit[i - 1:i + 2]).all():
        f_vertex = _parabola_vertex(np.log(focals[i - 1:i + 2]), misfit[i - 1:i + 2])
        fit = None if f_vertex is None else _fit_cone(found, float(np.exp(f_vertex)), principal, guess)
        if fit is not None and fit[2] <= best:
            best, f_best = fit[2], float(np.exp(f_vertex))
    if not best <= FOCAL_MIN_GAIN * ortho:
        return FocalFound(None, best, ortho)
    return FocalFound(f_best, best, ortho)


def _parabola_vertex(x: np.ndarray, y: np.ndarray) -> float | None:
    """The x of the vertex of the parabola through three points (x increasing), kept inside them;
    None when it opens downward."""
    d = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
    a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / d
    b = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / d
    if not a > 0:
        return None
    return float(np.clip(-b / (2 * a), x[0], x[2]))


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
