"""A key light placed by hand: ``builtin:key:az=30,el=25,size=30,kelvin=5000,fill=0.3,power=1``.

A soft disc of angular diameter ``size`` degrees toward azimuth ``az`` (degrees from the camera
axis +Z toward +X, the image's right) and elevation ``el`` (toward +Y, up), of colour temperature
``kelvin`` (the Planckian locus below 4000 K, the CIE daylight locus above 5000 K, blended
between; converted to linear Rec.709 with 6500 K neutral and the luminance kept), ``power``
times as strong as the capture's flash at the face (a white Lambertian surface facing it reads
``power``, as ``--light`` does); a fill from the mirrored side (azimuth ``-az``, half the
elevation, twice as wide, softer) at ``fill`` x the key's power, and an ambient of
:data:`AMBIENT` x the key's power from everywhere (radiance: a white surface reads it). Every
field is optional: :data:`DEFAULTS` is a flattering studio key, a little above and to the
side. Out-of-range fields get an :class:`InputError` naming the field and its range.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, fields

import numpy as np

from .colour import LUMINANCE
from .env_draw import add_light, disc, grid
from .errors import InputError
from .numerics import ACCUM, FLOAT

#: The fields' defaults: a soft warm-white key 30 deg to the image's right and 25 deg up.
DEFAULTS = {"az": 30.0, "el": 25.0, "size": 30.0, "kelvin": 5000.0, "fill": 0.3, "power": 1.0}
#: Each field's accepted range (inclusive): angles in degrees, kelvin in K, power in flashes, fill
#: as a share of the key (1: a second key).
RANGES = {"az": (-180.0, 180.0), "el": (-90.0, 90.0), "size": (1.0, 120.0), "kelvin": (1700.0, 25000.0),
          "fill": (0.0, 1.0), "power": (0.01, 100.0)}
#: The ambient's radiance as a share of the key's power (a white surface reads this much of it).
AMBIENT = 0.05
#: The disc's soft edge, as a share of its radius (a light with a diffuser: no hard rim).
EDGE_SOFTNESS = 0.25
#: The fill: twice the key's width (at least FILL_MIN_SIZE degrees), at half its elevation.
FILL_MIN_SIZE = 40.0
#: The colour temperature whose light is neutral (Rec.709's white point, D65).
NEUTRAL_KELVIN = 6500.0
#: Between these temperatures (K) the Planckian and the daylight locus are blended (the daylight
#: locus is defined from 4000 K; the two are 0.007 apart in xy there).
LOCUS_BLEND = (4000.0, 5000.0)

# XYZ -> linear Rec.709 (IEC 61966-2-1 / ITU-R BT.709 primaries, D65 white).
_XYZ_TO_709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]], dtype=ACCUM)


def planckian_xy(kelvin: float) -> tuple[float, float]:
    """CIE 1931 xy of a black body at ``kelvin`` (1667-25000 K): Kang et al. 2002's cubic fits."""
    t = float(kelvin)
    if t <= 4000.0:
        x = -0.2661239e9 / t**3 - 0.2343589e6 / t**2 + 0.8776956e3 / t + 0.179910
    else:
        x = -3.0258469e9 / t**3 + 2.1070379e6 / t**2 + 0.2226347e3 / t + 0.240390
    if t <= 2222.0:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif t <= 4000.0:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    return x, y


def daylight_xy(kelvin: float) -> tuple[float, float]:
    """CIE 1931 xy of the CIE daylight locus at ``kelvin`` (4000-25000 K; CIE 15:2004 eq. 3.3-3.4)."""
    t = float(kelvin)
    if t <= 7000.0:
        x = -4.6070e9 / t**3 + 2.9678e6 / t**2 + 0.09911e3 / t + 0.244063
    else:
        x = -2.0064e9 / t**3 + 1.9018e6 / t**2 + 0.24748e3 / t + 0.237040
    return x, -3.0 * x * x + 2.87 * x - 0.275


def kelvin_xy(kelvin: float) -> tuple[float, float]:
    """xy of a light of colour temperature ``kelvin``: the Planckian locus (warm lamps) below
    :data:`LOCUS_BLEND`, the daylight locus above, blended linearly between."""
    lo, hi = LOCUS_BLEND
    if kelvin <= lo:
        return planckian_xy(kelvin)
    if kelvin >= hi:
        return daylight_xy(kelvin)
    w = (kelvin - lo) / (hi - lo)
    (px, py), (dx, dy) = planckian_xy(kelvin), daylight_xy(kelvin)
    return (1 - w) * px + w * dx, (1 - w) * py + w * dy


def _xy_to_rgb(x: float, y: float) -> np.ndarray:
    xyz = np.array([x / y, 1.0, (1.0 - x - y) / y], dtype=ACCUM)
    return _XYZ_TO_709 @ xyz


def kelvin_rgb(kelvin: float) -> np.ndarray:
    """(3,) float64 linear Rec.709 colour of a light of colour temperature ``kelvin``, of
    luminance 1, with :data:`NEUTRAL_KELVIN` exactly (1, 1, 1) (the colour divided by the neutral
    one's, channel by channel: the small step between D65 and the daylight locus at 6500 K
    removed); channels below 0 (far outside Rec.709's gamut) are clipped to 0."""
    lo, hi = RANGES["kelvin"]
    if not (math.isfinite(kelvin) and lo <= kelvin <= hi):
        raise InputError(f"kelvin {kelvin}: use {lo:g} to {hi:g} K")
    rgb = _xy_to_rgb(*kelvin_xy(kelvin)) / _xy_to_rgb(*kelvin_xy(NEUTRAL_KELVIN))
    rgb = np.clip(rgb, 0.0, None)
    return rgb / float(LUMINANCE.astype(ACCUM) @ rgb)


def key_source(name: str) -> str | None:
    """A key light as a page or a request names it - ``key`` or ``key:az=60,el=20,...`` - as the
    ``builtin:`` source in its canonical spelling (every field: one cache entry per light); None
    for any other name; InputError naming a bad field."""
    if name != "key" and not name.startswith("key:"):
        return None
    return "builtin:" + KeyLight.parse(name[len("key:"):]).spec()


def direction(az_deg: float, el_deg: float) -> np.ndarray:
    """(3,) unit vector toward azimuth ``az_deg`` (from +Z toward +X) and elevation ``el_deg``
    (toward +Y), in camera space (+X right in the image, +Y up, +Z toward the camera)."""
    az, el = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)], dtype=ACCUM)


def add_disc_light(env: np.ndarray, dirs: np.ndarray, domega: np.ndarray, az: float, el: float, size: float,
                   colour, power: float, *, softness: float = EDGE_SOFTNESS, hole: float = 0.0) -> None:
    """Add to ``env`` (on the grid ``dirs``, ``domega``: :func:`relight.env_draw.grid`) a disc light
    of angular diameter ``size`` degrees toward (``az``, ``el``), its edge soft over ``softness``
    x its radius, a dark centre ``hole`` degrees across (a ring light; 0: none), of ``colour``
    (linear RGB) and ``power`` flashes (:func:`relight.env_draw.add_light`). The key light, its
    fill and the presets' lights are all drawn by this."""
    r = size / 2.0
    centre = direction(az, el)
    cover = disc(dirs, domega, centre, r, softness * r)
    if hole > 0:
        rh = hole / 2.0
        cover = np.clip(cover - disc(dirs, domega, centre, rh, softness * rh), 0.0, 1.0)
    add_light(env, cover, domega, colour, power)


@dataclass(frozen=True)
class KeyLight:
    """A key light's fields (see the module docstring); made by :meth:`parse` or directly, and
    checked either way."""

    az: float = DEFAULTS["az"]
    el: float = DEFAULTS["el"]
    size: float = DEFAULTS["size"]
    kelvin: float = DEFAULTS["kelvin"]
    fill: float = DEFAULTS["fill"]
    power: float = DEFAULTS["power"]

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            lo, hi = RANGES[f.name]
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or not lo <= v <= hi:
                raise InputError(f"key light field {f.name}={v!r}: use a number from {lo:g} to {hi:g}")
            object.__setattr__(self, f.name, float(v))

    @classmethod
    def parse(cls, spec: str) -> KeyLight:
        """``az=30,el=25,...`` (what follows ``builtin:key:``; empty: the defaults) -> a KeyLight;
        InputError naming the field for an unknown field, a repeated one or a value that is not
        a number in its range."""
        values: dict[str, float] = {}
        spec = spec.strip()
        for part in spec.split(",") if spec else []:
            m = re.fullmatch(r"\s*([A-Za-z]+)\s*=\s*([^=]*?)\s*", part)
            if m is None:
                raise InputError(f"key light {part!r}: write fields as name=value, e.g. "
                                 f"builtin:key:az=30,el=25 (fields: {', '.join(DEFAULTS)})")
            name, text = m.group(1).lower(), m.group(2)
            if name not in DEFAULTS:
                raise InputError(f"key light field {name!r}: use {', '.join(DEFAULTS)}")
            if name in values:
                raise InputError(f"key light field {name} given twice")
            try:
                values[name] = float(text)
            except ValueError:
                lo, hi = RANGES[name]
                raise InputError(f"key light field {name}={text!r}: use a number from {lo:g} to {hi:g}") from None
        return cls(**values)

    def spec(self) -> str:
        """The ``builtin:`` name of this light (every field, shortest form): parse(spec) == self."""
        return "key:" + ",".join(f"{f.name}={getattr(self, f.name):g}" for f in fields(self))

    def environment(self, width: int) -> np.ndarray:
        """The light as a (width / 2, width, 3) float32 lat-long map of linear radiance."""
        dirs, dw, env = grid(width)
        colour = kelvin_rgb(self.kelvin)
        add_disc_light(env, dirs, dw, self.az, self.el, self.size, colour, self.power)
        if self.fill > 0:  # twice the key's width, at least FILL_MIN_SIZE, softer
            add_disc_light(env, dirs, dw, -self.az, self.el / 2.0, max(2.0 * self.size, FILL_MIN_SIZE), colour,
                           self.fill * self.power, softness=2 * EDGE_SOFTNESS)
        env += (AMBIENT * self.power) * colour
        return env.astype(FLOAT)
