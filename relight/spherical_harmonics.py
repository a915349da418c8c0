"""Light as order-2 spherical harmonics (9 coefficients per channel): an environment's or a set
of directional lights' projection, the irradiance it gives a normal (Ramamoorthi & Hanrahan
2001's cosine-lobe convolution), and that irradiance as a quadratic form in the normal.

Used where only the light's low frequencies matter: the synthetic live clips' turning head, and
the live frame's shading beyond the bundle's face (hair, ears, neck). Directions are unit
vectors in whatever frame the caller's light is in; radiance linear RGB."""

from __future__ import annotations

import numpy as np

from relight.directions import equirect_directions, equirect_solid_angles


def sh9_basis(d: np.ndarray) -> np.ndarray:
    """Real spherical harmonics up to order 2 at unit directions (..., 3) -> (..., 9), float64.

    Order: Y00, Y1-1 (y), Y10 (z), Y11 (x), Y2-2 (xy), Y2-1 (yz), Y20, Y21 (xz), Y22.
    """
    d = np.asarray(d, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([
        np.full_like(x, 0.282095),
        0.488603 * y, 0.488603 * z, 0.488603 * x,
        1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3.0 * z * z - 1.0),
        1.092548 * x * z, 0.546274 * (x * x - y * y),
    ], axis=-1)


#: Lambertian convolution weights per SH band: pi, 2 pi / 3, pi / 4.
_SH_LAMBERT = np.array([np.pi] + [2.0 * np.pi / 3.0] * 3 + [np.pi / 4.0] * 5)


def environment_sh9(env: np.ndarray) -> np.ndarray:
    """(9, 3) SH coefficients of a lat-long environment's radiance (float64, exact texel solid angles)."""
    h, w = env.shape[:2]
    y = sh9_basis(equirect_directions(w, h))
    weight = equirect_solid_angles(w, h)[:, None, None]
    return np.einsum("hwk,hwc->kc", y * weight, env.astype(np.float64))


def lights_sh9(dirs: np.ndarray, power: np.ndarray) -> np.ndarray:
    """(9, 3) SH coefficients of directional lights: unit ``dirs`` (L, 3) with ``power`` (L, 3)
    (radiance x solid angle, as :func:`environment_sh9` weighs its texels)."""
    return sh9_basis(np.asarray(dirs, dtype=np.float64)).T @ np.asarray(power, dtype=np.float64)


def sh9_irradiance(coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Diffuse irradiance (..., 3) at unit normals (..., 3) from (9, 3) radiance coefficients.

    A uniform environment of radiance 1 gives pi (a white Lambertian surface reads 1).
    """
    return sh9_basis(normals) @ (_SH_LAMBERT[:, None] * coeffs)


def sh9_irradiance_matrix(coeffs: np.ndarray) -> np.ndarray:
    """(3, 4, 4) symmetric matrices M with E(n) = (n, 1)^T M (n, 1), equal to :func:`sh9_irradiance`
    (Ramamoorthi & Hanrahan 2001, eq. 12); a rotation of the normals is then a rotation of M."""
    c1, c2, c3, c4, c5 = 0.429043, 0.511664, 0.743125, 0.886227, 0.247708
    m = np.zeros((3, 4, 4))
    for ch in range(3):
        l00, l1m1, l10, l11, l2m2, l2m1, l20, l21, l22 = coeffs[:, ch]
        m[ch] = [[c1 * l22, c1 * l2m2, c1 * l21, c2 * l11],
                 [c1 * l2m2, -c1 * l22, c1 * l2m1, c2 * l1m1],
                 [c1 * l21, c1 * l2m1, c3 * l20, c2 * l10],
                 [c2 * l11, c2 * l1m1, c2 * l10, c4 * l00 - c5 * l20]]
    return m


#: Directions the SH light's brightest irradiance is searched over (a Fibonacci sphere).
SPHERE_POINTS = 2000

#: Upper-triangle entries (i, j) of a symmetric 4x4 form over (x, y, z, 1), the constant (3, 3) last.
MONOMIALS = (np.array([0, 1, 2, 0, 0, 1, 0, 1, 2, 3]), np.array([0, 1, 2, 1, 2, 2, 3, 3, 3, 3]))
