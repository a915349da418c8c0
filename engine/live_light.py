"""The light on the live face, measured from the live face.

The bundle is a linear map from light to pixels, so the light that falls on the face in a live
frame can be fitted to the frame: the frame's face, taken back into the reference's geometry,
is the bundle relit by some non-negative light, times the live camera's gain and white balance.

* Light model, in the head's frame (where the maps are): a smooth part - ``LOBES`` broad lobes
  over the sphere, von Mises-Fisher bumps of ``LOBE_DEG``, each one flash of power - plus sharp
  lights: single map texels (5.6 degrees at 64x32) near the strongest lobes, so a window or a
  lamp casts the hard shadows it does (a broad lobe alone would soften the nose's shadow and the
  ratio to it would leave the live shadow in place). Its shape is fitted on luminance; its colour
  (the light's and the camera's white balance together) is one gain per channel. Lobes the
  bundle has no texels for (behind the head) get no weight.
* Fit: non-negative least squares on sampled face pixels (their maps, read once), regularised
  toward the previous frame's light (a defined answer when the face shows little), with robust
  weights (Tukey's biweight on the luminance residual): what the bundle cannot explain - eyes,
  mouth, hair, glints - stops pulling the light. The weights live on the reference's pixels, so
  each frame reuses the last frame's and refines them once. Clipped and black pixels are left
  out. The light is smoothed over time (exponential, ``SMOOTH_S``).
* Status: ``ok``; ``few pixels`` (fewer than ``MIN_PIXELS`` usable: the last light is kept);
  ``dark`` / ``clipped`` (most of the face under the noise floor or saturated: fitted on what is
  left, and flagged).

Colours: linear Rec.709, the live frame's exposure. Directions in what is reported: camera space
(+X right, +Y up, +Z toward the camera), the direction the light comes from.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls

from relight.colour import LUMINANCE
from relight.numerics import EPS, EPS_NORM, RANK_REL, TINY_SCALE

#: Broad lobes over the sphere (Fibonacci directions) and their angular width (degrees, the von
#: Mises-Fisher sigma).
LOBES = 48
LOBE_DEG = 22.0
#: Sharp lights: the texels within SHARP_REACH_DEG of lobes holding at least SHARP_SHARE of the
#: strongest lobe's weight, at most SHARP_MAX of them (the nearest first).
SHARP_REACH_DEG = 25.0
SHARP_SHARE = 0.15
SHARP_MAX = 64
#: Face pixels sampled for the fit (at most), and the stride over them of the colour fit.
SAMPLES = 2000
COLOUR_STRIDE = 4
#: Fewest usable pixels for a fit.
MIN_PIXELS = 64
#: Pixels read as clipped at this linear value (any channel) and as black below this one.
CLIP = 0.95
BLACK = 2e-4
#: Regularisation toward the previous light, relative to the mean diagonal of the normal equations.
RIDGE = 2e-3
#: Robust passes on the first frame (later frames: one, from the last frame's weights), and
#: Tukey's biweight constant (in robust standard deviations of the residual).
FIRST_PASSES = 3
TUKEY_C = 4.685
#: Temporal smoothing of the light: exponential, this time constant (s).
SMOOTH_S = 0.12


@dataclass
class LiveLight:
    """One frame's light estimate (see the module docstring)."""

    direction: tuple[float, float, float]  # dominant direction (by what it lights of the face), camera space
    intensity: float                       # total luminance, flashes of power (live exposure)
    colour: tuple[float, float, float]     # rgb of the light, luminance 1
    residual: float                        # RMS fit residual relative to the face's RMS (robust pixels)
    spread: float                          # robust scatter of live / fitted (1.4826 MAD of the ratio - 1)
    pixels: int                            # pixels used
    status: str = "ok"
    notes: list = field(default_factory=list)

    def as_json(self) -> dict:
        return {"direction": [round(v, 4) for v in self.direction], "intensity": round(self.intensity, 5),
                "colour": [round(v, 4) for v in self.colour],
                "residual": round(self.residual, 4) if self.residual == self.residual else None,
                "spread": round(self.spread, 4) if self.spread == self.spread else None,
                "pixels": self.pixels, "status": self.status}


def lobe_lights(texel_dirs: np.ndarray, solid_angle: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(T, n) texel light of each lobe (power per texel over pi, flash units: each column sums to 1
    over the whole sphere; texels not stored in the bundle receive nothing)."""
    from relight.directions import equirect_directions, equirect_solid_angles

    kappa = 1.0 / np.radians(LOBE_DEG) ** 2
    full = equirect_directions(64, 32).reshape(-1, 3)
    full_sa = np.repeat(equirect_solid_angles(64, 32), 64)
    norm = (np.exp(kappa * (full @ dirs.T - 1.0)) * full_sa[:, None]).sum(axis=0)
    return np.exp(kappa * (texel_dirs @ dirs.T - 1.0)) * solid_angle[:, None] / norm[None]


def _nnls(a: np.ndarray, y: np.ndarray, prior: np.ndarray, ridge: float = RIDGE) -> np.ndarray:
    """argmin |a w - y|^2 + lam |w - prior|^2 over w >= 0 (lam = ridge x the mean diagonal of a^T a)."""
    n = a.shape[1]
    g = a.T @ a
    lam = ridge * max(float(np.trace(g)) / max(n, 1), TINY_SCALE)
    lhs = g + lam * np.eye(n)
    rhs = a.T @ y + lam * prior
    try:
        chol = np.linalg.cholesky(lhs)
    except np.linalg.LinAlgError:
        chol = np.linalg.cholesky(lhs + EPS_NORM * float(np.trace(lhs)) * np.eye(n))
    w, _ = nnls(chol.T, np.linalg.solve(chol, rhs), maxiter=20 * n)
    return w


@dataclass(frozen=True)
class LightBasis:
    """What :class:`LightEstimator` fits with - the sampled pixels' maps in the shapes the fit
    reads and the lobes - made once from a bundle's maps (:meth:`make`) and never changed (its
    arrays read-only): every estimator on the same bundle and pixels shares one (:func:`shared_basis`).
    """

    texel_dirs: np.ndarray  # (T, 3) float64 the stored texels' directions
    lum_maps: np.ndarray  # (P_s, T) float32 the maps' luminance
    maps_t: np.ndarray  # (T, P_s, 3) float32 texel-major maps (a frame reads the rows of a few texels)
    lum_t: np.ndarray  # (T, P_s) float32 texel-major luminance
    lobe_dirs: np.ndarray  # (n, 3) the lobes the bundle can show
    lobes: np.ndarray  # (T, n) their texel lights
    lobe_lum: np.ndarray  # (P_s, n) float32 each lobe's luminance on the pixels
    lobe_rgb: np.ndarray  # (P_s, 3, n) float32 and colour
    lobe_pinv: np.ndarray  # (n, T) a texel light's nearest lobe weights
    lobe_cos: np.ndarray  # (T, n) texel-lobe cosines
    reach: np.ndarray  # (T,) float64 how much each texel lights the face

    @classmethod
    def make(cls, maps: np.ndarray, texel_dirs: np.ndarray, solid_angle: np.ndarray) -> LightBasis:
        """From ``maps`` (P_s, 3, T) float32 - the bundle's reflectance maps at the sampled pixels,
        in capture units (multiplied by its sample_scale) -, ``texel_dirs`` (T, 3) and
        ``solid_angle`` (T,) of the stored texels."""
        from relight.directions import fibonacci_sphere

        maps = np.asarray(maps, dtype=np.float32)
        texel_dirs = np.asarray(texel_dirs, dtype=np.float64)
        lum_maps = np.einsum("pct,c->pt", maps, LUMINANCE.astype(np.float32))
        dirs = fibonacci_sphere(LOBES)
        lobes = lobe_lights(texel_dirs, np.asarray(solid_angle, np.float64), dirs)  # (T, n)
        reach = (lum_maps @ lobes.astype(np.float32)).max(axis=0)
        live = reach > RANK_REL * max(float(reach.max(initial=0.0)), TINY_SCALE)  # lobes the bundle can show
        lobe_dirs, lobes = dirs[live], lobes[:, live]
        basis = cls(texel_dirs=texel_dirs, lum_maps=lum_maps,
                    maps_t=np.ascontiguousarray(maps.transpose(2, 0, 1)), lum_t=np.ascontiguousarray(lum_maps.T),
                    lobe_dirs=lobe_dirs, lobes=lobes, lobe_lum=lum_maps @ lobes.astype(np.float32),
                    lobe_rgb=np.einsum("pct,tn->pcn", maps, lobes.astype(np.float32)),
                    lobe_pinv=np.linalg.pinv(lobes), lobe_cos=texel_dirs @ lobe_dirs.T,
                    reach=lum_maps.mean(axis=0, dtype=np.float64))
        for value in vars(basis).values():
            value.flags.writeable = False
        return basis


#: Bases kept per bundle (:func:`shared_basis`): a bundle's frame paths use one set of pixels.
KEPT_BASES = 2


def shared_basis(bundle, pixels: np.ndarray, sample_scale: float) -> LightBasis:
    """The :class:`LightBasis` of ``bundle``'s head pixels ``pixels`` (an index array) at
    ``sample_scale``, made on first use and kept with the loaded bundle (at most
    :data:`KEPT_BASES`): every frame path on a bundle - a service's stream clients and sessions,
    each made in a request - shares it instead of making its maps again (1.2 s of a small bundle)."""
    import hashlib

    pixels = np.ascontiguousarray(pixels, dtype=np.int64)
    key = (hashlib.blake2b(pixels.tobytes(), digest_size=16).digest(), float(sample_scale))
    kept = bundle.__dict__.setdefault("_light_bases", {})
    basis = kept.get(key)
    if basis is None:
        maps = bundle.pixel_maps(pixels, padded=False).astype(np.float32) * np.float32(sample_scale)
        basis = LightBasis.make(maps, bundle.texel_dirs, bundle.solid_angle)
        while len(kept) >= KEPT_BASES:
            kept.pop(next(iter(kept)))
        kept[key] = basis
    return basis


class LightEstimator:
    """Fits the live light to sampled face pixels of a bundle (module docstring).

    maps : (P_s, 3, T) float32 the bundle's reflectance maps at the sampled pixels (capture units:
    multiplied by the bundle's sample_scale); texel_dirs (T, 3), solid_angle (T,) of the stored
    texels - or ``basis``, a :class:`LightBasis` made from them (shared: :func:`shared_basis`).
    The estimator's own state is its robust weights and the smoothed light.
    """

    def __init__(self, maps: np.ndarray | None = None, texel_dirs: np.ndarray | None = None,
                 solid_angle: np.ndarray | None = None, *, basis: LightBasis | None = None):
        if basis is None:
            basis = LightBasis.make(maps, texel_dirs, solid_angle)
        self.basis = basis
        for name, value in vars(basis).items():  # (read-only: the fit reads them by these names)
            setattr(self, name, value)
        self.robust = np.ones(basis.lum_maps.shape[0])
        self.light = None  # (T, 3) the smoothed light in the texels
        self.t = None
        self.spread = float("nan")

    def reset(self) -> None:
        self.robust[:] = 1.0
        self.light = None
        self.t = None

    def texel_light(self) -> np.ndarray:
        """(T, 3) the current light in the bundle's texels (zeros before the first fit)."""
        return self.light if self.light is not None else np.zeros((self.texel_dirs.shape[0], 3))

    def fit(self, live: np.ndarray, valid: np.ndarray, t: float, rotation: np.ndarray | None = None) -> LiveLight:
        """The light of one frame. live : (P_s, 3) float32 linear colours of the sampled pixels in
        the frame (in the maps' order); valid : (P_s,) bool where the frame shows the pixel (inside
        it, facing the camera); t : seconds (for the smoothing); rotation : the head's 3x3
        rotation (camera from head), to report the direction in camera space."""
        live = np.asarray(live, dtype=np.float64)
        use = np.asarray(valid, dtype=bool) & np.isfinite(live).all(axis=1)
        clipped = (live >= CLIP).any(axis=1)
        black = (live <= BLACK).all(axis=1)
        notes: list = []
        status = "ok"
        n_valid = int(use.sum())
        if n_valid and clipped[use].mean() > 0.5:
            status = "clipped"
            notes.append("most of the face is saturated: the frame is overexposed")
        elif n_valid and black[use].mean() > 0.5:
            status = "dark"
            notes.append("most of the face is black: the frame is underexposed")
        use &= ~clipped & ~black
        if int(use.sum()) < MIN_PIXELS:
            notes.append(f"{int(use.sum())} usable face pixels (need {MIN_PIXELS}): the last light is kept")
            # A saturated or black face says so (the reason there are few pixels), else "few pixels".
            return self._report(rotation, residual=float("nan"), pixels=int(use.sum()),
                                status=status if status != "ok" else "few pixels", notes=notes)
        idx = np.flatnonzero(use)
        y = live[idx]
        yl = y @ LUMINANCE.astype(np.float64)
        prev = self.light
        first = prev is None
        for _ in range(FIRST_PASSES if first else 1):
            sw = np.sqrt(self.robust[idx])
            # 1. the smooth part
            a_b = self.lobe_lum[idx].astype(np.float64)
            prior_b = np.zeros(a_b.shape[1]) if first else self._project(prev)
            w_b = _nnls(a_b * sw[:, None], yl * sw, prior_b)
            # 2. sharp lights near the strongest lobes, fitted with the lobes
            cand = self._sharp_texels(w_b)
            a = np.concatenate([a_b, self.lum_t[np.ix_(cand, idx)].T.astype(np.float64)], axis=1)
            prior_t = np.zeros(cand.size) if first else \
                np.maximum(prev[cand] @ LUMINANCE - (self.lobes[cand] @ prior_b), 0.0)
            prior = np.concatenate([w_b, prior_t])
            w = _nnls(a * sw[:, None], yl * sw, prior)
            w_lobes, w_tex = w[:w_b.size], w[w_b.size:]
            shape = self.lobes @ w_lobes
            shape[cand] += w_tex
            fit_l = a @ w
            r = np.abs(yl - fit_l)
            scale = 1.4826 * float(np.median(r))  # over every usable pixel: excluded ones can come back
            u = r / (TUKEY_C * max(scale, EPS_NORM * max(float(np.median(yl)), EPS)))
            self.robust[idx] = np.where(u < 1.0, (1.0 - u * u) ** 2, 0.0)
        # 3. colour: one gain per channel on the fitted shape
        sub = idx[::COLOUR_STRIDE]
        fit_c = self.lobe_rgb[sub] @ w_lobes + np.tensordot(w_tex, self.maps_t[np.ix_(cand, sub)], axes=(0, 0))
        y = live[sub]
        wts = self.robust[sub][:, None]
        gains = (wts * fit_c * y).sum(axis=0) / np.maximum((wts * fit_c * fit_c).sum(axis=0), TINY_SCALE)
        gains = np.where(np.isfinite(gains) & (gains > 0), gains, 0.0)
        lum_gain = float(gains @ LUMINANCE)
        gains = gains / lum_gain if lum_gain > 0 else np.ones(3)
        light = shape[:, None] * gains[None, :]
        keep = self.robust[idx] > 0
        rms = float(np.sqrt(np.mean(yl[keep] ** 2))) if keep.any() else 0.0
        res = float(np.sqrt(np.mean((yl - fit_l)[keep] ** 2))) / rms if rms > 0 else float("nan")
        lit = fit_l > 0.05 * max(float(np.median(fit_l)), EPS)
        spread = 1.4826 * float(np.median(np.abs(yl[lit] / fit_l[lit] - 1.0))) if lit.any() else float("nan")
        if prev is not None and self.t is not None and t > self.t:
            k = 1.0 - np.exp(-(t - self.t) / SMOOTH_S)
            light = prev + k * (light - prev)
        self.light, self.t = light, float(t)
        self.spread = spread
        return self._report(rotation, residual=res, pixels=int(keep.sum()), status=status, notes=notes)

    def _project(self, light: np.ndarray) -> np.ndarray:
        """Lobe weights whose light is nearest the given texel light (the prior of the smooth part)."""
        return np.maximum(self.lobe_pinv @ (light @ LUMINANCE), 0.0)

    def _sharp_texels(self, w_b: np.ndarray) -> np.ndarray:
        """Texel ids of the sharp lights: near the strongest lobes (module constants)."""
        if not (w_b.max(initial=0.0) > 0):
            return np.zeros(0, dtype=np.int64)
        strong = w_b >= SHARP_SHARE * w_b.max()
        near = self.lobe_cos[:, strong].max(axis=1)
        cand = np.flatnonzero(near >= np.cos(np.radians(SHARP_REACH_DEG)))
        if cand.size > SHARP_MAX:
            cand = cand[np.argsort(-near[cand])[:SHARP_MAX]]
        return np.sort(cand)

    def _report(self, rotation, *, residual, pixels, status, notes) -> LiveLight:
        light = self.light
        if light is None:
            return LiveLight(direction=(0.0, 0.0, 1.0), intensity=0.0, colour=(1.0, 1.0, 1.0), residual=residual,
                             spread=float("nan"), pixels=pixels, status=status, notes=notes)
        lum = light @ LUMINANCE.astype(np.float64)
        total = float(lum.sum())
        # The dominant direction: each texel's light weighted by how much of the face it lights
        # (grazing light that reaches little of the face does not swing it).
        d = (lum * self.reach) @ self.texel_dirs
        norm = float(np.linalg.norm(d))
        d = d / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
        if rotation is not None:
            d = np.asarray(rotation, dtype=np.float64) @ d
        rgb = light.sum(axis=0)
        colour = rgb / total if total > 0 else np.ones(3)
        return LiveLight(direction=tuple(float(v) for v in d), intensity=total,
                         colour=tuple(float(v) for v in colour), residual=residual, spread=self.spread, pixels=pixels,
                         status=status, notes=notes)
