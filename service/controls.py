"""The JSON controls a live client sends (the websocket's text messages, the WebRTC data
channel's): ``{"env": "sunset", "rotation": [yaw, pitch, roll], "strength": 0.8, "mode": "paste",
"exposure": 0, "spin": 10}``, any subset; ``env`` a preset, a key light (``"key:az=60,el=20"``)
or ``"current"`` (the service's own again: an upload), ``rotation`` the environment's (its yaw is
the turn: :data:`relight.directions.ENV_TURN_RANGE_DEG`), ``spin`` its turn per second. One
parser for both transports."""

from __future__ import annotations

import json

from ..directions import ENV_SPIN_RANGE_DEG_S
from ..engine.composite import MODES
from ..engine.frame_settings import EXPOSURE_RANGE_EV
from .codec import parse_rotation
from .errors import ServiceError
from .settings import PRESETS

#: Ranges of the numeric controls.
RANGES = {"strength": (0.0, 1.0), "exposure": EXPOSURE_RANGE_EV, "spin": ENV_SPIN_RANGE_DEG_S}
#: Longest control message read (bytes).
MAX_CONTROL = 4096
#: Longest environment name a client may send (a key light with every field is ~60 characters).
MAX_ENV_NAME = 200


def environment_source(name, what: str = "env", kind: str = "bad_control") -> str:
    """A client's environment name - a preset (:data:`.settings.PRESETS`, e.g. ``sunset``) or a key
    light (``key:az=60,el=20,...``, :mod:`relight.key_light`) - as the ``builtin:`` source the
    engine loads (a key light in its canonical spelling: one cache entry per light); ServiceError
    (422, ``kind``) naming the field ``what`` and what to send otherwise."""
    if isinstance(name, str) and name in PRESETS:
        return f"builtin:{name}"
    if isinstance(name, str) and len(name) <= MAX_ENV_NAME:
        from relight.errors import InputError
        from relight.key_light import key_source

        try:
            source = key_source(name)
        except InputError as exc:
            raise ServiceError(422, kind, f"{what}: {exc}") from None
        if source is not None:
            return source
    raise ServiceError(422, kind,
                       f"{what} {name!r}: use one of {', '.join(PRESETS)} or a key light key:az=30,el=25,size=30,"
                       "kelvin=5000,fill=0.3,power=1 (every field optional)")


def new_settings() -> dict:
    """A client's settings before any control (None: the service's own)."""
    return {"env": None, "rotation": None, "strength": None, "mode": None, "exposure": None, "spin": None}


def parse_control(text) -> object:
    """A control message's text -> its JSON value; ServiceError (422, ``bad_control``) for binary
    data, text over :data:`MAX_CONTROL` bytes or anything that is not JSON (nesting too deep for
    the parser included)."""
    if not isinstance(text, str) or len(text) > MAX_CONTROL:
        raise ServiceError(422, "bad_control", f"controls are JSON text of at most {MAX_CONTROL} bytes")
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise ServiceError(422, "bad_control", f"control message is not JSON ({type(exc).__name__})") from None


def apply_control(settings: dict, doc) -> None:
    """Check the control message ``doc`` (parsed JSON) and apply it to ``settings``; raises
    ServiceError (422, kind ``bad_control``) saying what to change, leaving ``settings`` as it was."""
    if not isinstance(doc, dict):
        raise ServiceError(422, "bad_control", "control messages are JSON objects")
    new = {}
    if "env" in doc:  # "current": the service's own (an upload, PUT /v1/environment)
        new["env"] = None if doc["env"] == "current" else environment_source(doc["env"])
    if "rotation" in doc:
        rot = doc["rotation"]
        if not isinstance(rot, list) or len(rot) != 3:
            raise ServiceError(422, "bad_control", "rotation: a list of three numbers [yaw, pitch, roll] (degrees)")
        new["rotation"] = parse_rotation(",".join(str(v) for v in rot))
    for key, (lo, hi) in RANGES.items():
        if key in doc:
            v = doc[key]
            if isinstance(v, bool) or not isinstance(v, int | float) or not (lo <= v <= hi):
                raise ServiceError(422, "bad_control", f"{key} {v!r}: use {lo:g} to {hi:g}")
            new[key] = float(v)
    if "mode" in doc:
        if doc["mode"] not in MODES:
            raise ServiceError(422, "bad_control", f"mode: one of {', '.join(MODES)}")
        new["mode"] = doc["mode"]
    settings.update(new)
