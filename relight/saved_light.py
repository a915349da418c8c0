"""A light saved by name: a small JSON file - what environment, turned how far, how bright - that
``--env NAME.json`` (and :func:`relight.load_environment`, which loads, turns and exposes what it
names) gives back. This module reads, checks and writes the file.

Format (UTF-8 JSON object, at most :data:`MAX_BYTES`)::

    {"relight_light": 1, "env": "builtin:key:az=-40,el=25,size=30,kelvin=3200,fill=0.3,power=1",
     "turn": 20.0, "exposure": 0.5}

``env`` is any environment source but another saved light: a ``builtin:`` name, a key light, a
``photo:PATH`` or a map file; a relative path is relative to the JSON file's folder (a saved
photo is kept beside it). ``turn`` (degrees, the convention of
:data:`relight.directions.ENV_TURN_RANGE_DEG`) and ``exposure`` (EV) are baked into the map when it
is loaded; both optional (0).
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

from .errors import InputError

#: The format's version, and the largest file read (bytes).
VERSION = 1
MAX_BYTES = 16 * 1024
#: A saved light's name: letters, digits, '-', '_' and '.', 1 to 64 of them, not starting with '.'.
NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}$")


def light_document(env: str, turn: float = 0.0, exposure: float = 0.0) -> dict:
    """The JSON object of a saved light (checked as :func:`read_light` checks a file)."""
    doc = {"relight_light": VERSION, "env": str(env), "turn": float(turn), "exposure": float(exposure)}
    _check(doc, "the light")
    return doc


def _check(doc, where: str) -> None:
    from .directions import ENV_TURN_RANGE_DEG

    if not isinstance(doc, dict) or doc.get("relight_light") != VERSION:
        raise InputError(f"{where}: not a saved light (a JSON object with \"relight_light\": {VERSION})")
    env = doc.get("env")
    if not isinstance(env, str) or not env or len(env) > 4096:
        raise InputError(f"{where}: \"env\" must name an environment (a builtin: name, photo:PATH or a map file)")
    if env.lower().endswith(".json"):
        raise InputError(f"{where}: \"env\" names another saved light; name its environment instead")
    lo, hi = ENV_TURN_RANGE_DEG
    for key, (a, b) in (("turn", (lo, hi)), ("exposure", (-20.0, 20.0))):
        v = doc.get(key, 0.0)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or not a <= v <= b:
            raise InputError(f"{where}: \"{key}\" {v!r}: use a number from {a:g} to {b:g}")


def read_light(path: str | os.PathLike) -> dict:
    """A saved light's document, checked; InputError saying what is wrong otherwise."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file; check the path")
    if p.stat().st_size > MAX_BYTES:
        raise InputError(f"{p}: more than {MAX_BYTES} bytes; a saved light is a small JSON file")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise InputError(f"{p}: not JSON ({type(exc).__name__}); save the light again") from None
    _check(doc, str(p))
    return doc


def environment_source(doc: dict, folder: Path) -> str:
    """The environment source a saved light names, a relative path taken from ``folder``."""
    env = doc["env"]
    if env.startswith("builtin:"):
        return env
    prefix = "photo:" if env.startswith("photo:") else ""
    path = Path(env[len(prefix):])
    return prefix + str(path if path.is_absolute() else folder / path)


def save_light(folder: str | os.PathLike, name: str, doc: dict) -> Path:
    """Write ``doc`` (:func:`light_document`) as ``folder/name.json``, atomically; the path."""
    from .imageio import atomic_path

    if not NAME.match(name or ""):
        raise InputError(f"light name {name!r}: use 1 to 64 letters, digits, '-', '_' or '.'")
    _check(doc, "the light")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"{name}.json"
    with atomic_path(out) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return out
