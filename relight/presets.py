"""Lighting presets people recognise - ``builtin:overcast``, ``golden-hour``, ``office``,
``stage``, ``ring-light`` - each a key, fill and sky made with the key light's machinery
(:mod:`relight.key_light`: discs of a colour temperature and a power in flashes; a sky dome of a
zenith and a horizon colour temperature). The studio's own built-ins (``studio``, ``sunset``,
``window``, ``uniform``, ``room``) stay as they are in :mod:`relight.envmap`: the synthetic
studio's truth, the benchmarks and the demo use them.

Every preset is a list of :class:`Disc` lights and one :class:`Sky`; powers are in flashes (a
white surface facing a disc reads its power), radiances of the sky in flash units (a white
surface under a uniform sky of radiance 1 reads 1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .env_draw import grid
from .key_light import add_disc_light, kelvin_rgb
from .numerics import FLOAT


@dataclass(frozen=True)
class Disc:
    """A soft disc light (see :class:`relight.key_light.KeyLight`'s key): ``size`` its angular
    diameter (degrees), ``hole`` a dark centre's diameter (a ring light), ``power`` in flashes."""

    az: float
    el: float
    size: float
    kelvin: float
    power: float
    hole: float = 0.0


@dataclass(frozen=True)
class Sky:
    """A sky dome over a ground: radiance ``zenith`` overhead falling to ``horizon`` at the
    horizon (colour temperatures ``zenith_k``, ``horizon_k``), ``ground`` below (a dim, warm
    reflection of it); ``ambient`` a uniform radiance added everywhere (a room's walls)."""

    zenith: float = 0.0
    horizon: float = 0.0
    zenith_k: float = 6500.0
    horizon_k: float = 6500.0
    ground: float = 0.0
    ambient: float = 0.0
    ambient_k: float = 6500.0


def render_preset(lights: tuple[Disc, ...], sky: Sky, width: int) -> np.ndarray:
    """The lat-long map (width / 2, width, 3) float32 of linear radiance of a preset."""
    dirs, dw, env = grid(width)
    y = dirs[..., 1:2]
    if sky.zenith or sky.horizon:
        t = np.sqrt(np.clip(y, 0.0, 1.0))  # 0 at the horizon, 1 overhead
        zen, hor = kelvin_rgb(sky.zenith_k) * sky.zenith, kelvin_rgb(sky.horizon_k) * sky.horizon
        above = hor * (1.0 - t) + zen * t
        blend = np.clip(y / np.sin(np.radians(2.0)) + 0.5, 0.0, 1.0)  # a soft horizon, 2 degrees
        below = kelvin_rgb(0.5 * (sky.zenith_k + sky.horizon_k)) * sky.ground
        env += above * blend + below * (1.0 - blend)
    if sky.ambient:
        env += sky.ambient * kelvin_rgb(sky.ambient_k)
    for lt in lights:
        add_disc_light(env, dirs, dw, lt.az, lt.el, lt.size, kelvin_rgb(lt.kelvin), lt.power, hole=lt.hole)
    return env.astype(FLOAT)


# The presets: their lights and sky, each with what it is meant to look like.
PRESET_PARTS: dict[str, tuple[tuple[Disc, ...], Sky]] = {
    # a bright, even, cool sky from above; soft shadows under the brows and chin
    "overcast": ((Disc(az=0, el=70, size=120, kelvin=6800, power=0.35),),
                 Sky(zenith=0.55, horizon=0.25, zenith_k=7000, horizon_k=6500, ground=0.08)),
    # a low warm sun to the image's right, a deep blue sky behind, long soft shadows
    "golden-hour": ((Disc(az=65, el=8, size=4, kelvin=2900, power=1.1),),
                    Sky(zenith=0.10, horizon=0.16, zenith_k=12000, horizon_k=4200, ground=0.04)),
    # ceiling panels overhead, a window to the image's left, white walls
    "office": ((Disc(az=0, el=65, size=45, kelvin=4000, power=0.6),
                Disc(az=-70, el=10, size=50, kelvin=6500, power=0.35)),
               Sky(ambient=0.12, ambient_k=4500)),
    # a hard warm spot from above the camera, a cool rim from behind, a dark house
    "stage": ((Disc(az=0, el=40, size=6, kelvin=3200, power=1.4),
               Disc(az=160, el=35, size=10, kelvin=9000, power=0.7)),
              Sky(ambient=0.01, ambient_k=3200)),
    # a ring around the lens: flat, shadowless, a ring in each eye
    "ring-light": ((Disc(az=0, el=0, size=30, kelvin=5600, power=1.0, hole=18),),
                   Sky(ambient=0.04, ambient_k=5600)),
}

#: The presets' makers, by name (``builtin:NAME``), each ``f(width) -> map``.
PRESETS: dict[str, Callable[[int], np.ndarray]] = {
    name: (lambda width, parts=parts: render_preset(*parts, width)) for name, parts in PRESET_PARTS.items()
}
