"""The targets of ``relight bench fuzz``: each reader of hostile input (the function a user's
file or a client's request reaches first, then what the product does with what it returned),
its seeds, the structured inputs it gets beside the byte edits (a bundle header rewritten with
its checksums made right, an image header claiming another size, JSON control messages), and
what counts as a refusal rather than a crash."""

from __future__ import annotations

import json
import re
import shutil
import tempfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .fuzz_mutations import INTERESTING_INTS
from .fuzz_seeds import seed_bundle, seed_envmaps, seed_frames, seed_lp, seed_videos


@dataclass
class Target:
    """One reader under test: ``run(data)`` parses one input and uses what it returned."""

    name: str
    what: str
    seeds: list[bytes]
    run: object  # Callable[[bytes], None]
    structured: object = None  # optional Callable[[st], strategy of bytes] beside the byte edits
    caps: str = ""


def expected_refusal(exc: BaseException) -> bool:
    """Whether ``exc`` is one of the refusals we mean to give (our errors, an HTTP 4xx)."""
    from relight.errors import InputError, NumericalError
    from relight.service.errors import ServiceError

    if isinstance(exc, InputError | NumericalError):
        return True
    return isinstance(exc, ServiceError) and 400 <= exc.status < 500


class Scratch:
    """A private folder for the files a target must read from disk."""

    def __init__(self, work: Path):
        # Beside the seeds: a process killed by an input (a crash of native code) leaves the
        # input there for a look.
        self.dir = Path(tempfile.mkdtemp(prefix="scratch-", dir=work))

    def write(self, name: str, data: bytes) -> Path:
        p = self.dir / name
        p.write_bytes(data)
        return p

    def close(self):
        shutil.rmtree(self.dir, ignore_errors=True)


def _bundle_target(work: Path, scratch: Scratch) -> Target:
    from relight import load_bundle

    seed = seed_bundle(work)

    env = None

    def run(data: bytes) -> None:
        nonlocal env
        b = load_bundle(scratch.write("f.bundle", data))
        use_bundle(b)
        if data != seed:  # an accepted changed bundle goes through the relighter (PoCL) as served
            from relight import Relighter, load_environment

            env = load_environment("builtin:sunset", width=64) if env is None else env
            out = Relighter(b).relight(env)
            if not np.isfinite(out).all():
                raise AssertionError("an accepted bundle relit to non-finite values")

    def crafted(st):
        return st.tuples(st.integers(0, 10 ** 6), st.sampled_from(INTERESTING_INTS + (-5, 0.5, "x", None, [],
                                                                                       {}, [1], [2 ** 40, 2]))
                         ).map(lambda pv: craft_bundle(seed, pv[0], pv[1]))

    return Target("bundle", "load_bundle, its accessors, then the relighter on PoCL", [seed], run, crafted,
                  caps="header <= 64 MiB; arrays memory-mapped; fields checked against each other")


def use_bundle(b) -> None:
    """What the relighter and the service read of a loaded bundle (a few pixels' maps)."""
    _ = b.background, b.mask, b.frame_index, b.ambient_frame(), b.room_light
    _ = b.texel_dirs, b.solid_angle
    n = b.n_pixels
    if n:
        idx = np.arange(min(n, 4))
        b.pixel_maps(idx)
        b.full_map(0)
    if b.recipe_stored:
        _ = b.recipe


def _json_paths(doc, prefix=()):
    """Every (path, value) of a JSON document, depth first."""
    yield prefix, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _json_paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _json_paths(v, prefix + (i,))


def _json_set(doc, path, value):
    if not path:
        return value
    cur = doc
    for k in path[:-1]:
        cur = cur[k]
    cur[path[-1]] = value
    return doc


def craft_bundle(seed: bytes, which, value) -> bytes:
    """``seed`` with one value of its JSON header replaced and every checksum made right again.
    which : a path into the header (``("meta", "crop_origin", 0)``) or a number choosing one of
    its leaves (and of the arrays' descriptions)."""
    import struct

    prefix = struct.Struct("<8sIIQ")
    magic, version, _crc, hlen = prefix.unpack_from(seed)
    header = seed[prefix.size:prefix.size + hlen]
    doc = json.loads(header)
    if isinstance(which, int):
        paths = [p for p, v in _json_paths(doc) if p and not isinstance(v, dict | list) or len(p) == 2]
        which = paths[which % len(paths)]
    doc = _json_set(doc, tuple(which), value)
    body = bytearray(seed)
    new = json.dumps(doc).encode()
    if len(new) > hlen:
        return bytes(body)  # would move the arrays: left as it was
    new = new + b" " * (hlen - len(new))
    body[prefix.size:prefix.size + hlen] = new
    arrays = doc.get("arrays") if isinstance(doc, dict) else None
    if isinstance(arrays, dict):  # the arrays' checksums over whatever the header now says they are
        for spec in arrays.values():
            try:
                off, nb = int(spec["offset"]), int(spec["nbytes"])
                if 0 <= off and 0 <= nb and off + nb <= len(body):
                    spec["crc32"] = zlib.crc32(bytes(body[off:off + nb]))
            except (KeyError, TypeError, ValueError):
                continue
        new = json.dumps(doc).encode()
        if len(new) <= hlen:
            body[prefix.size:prefix.size + hlen] = new + b" " * (hlen - len(new))
    body[:prefix.size] = prefix.pack(magic, version, zlib.crc32(bytes(body[prefix.size:prefix.size + hlen])), hlen)
    return bytes(body)


def _lp_target(work: Path, scratch: Scratch) -> Target:
    from relight.pipeline.image_set import read_lp

    seeds = seed_lp(work)

    def run(data: bytes) -> None:
        for _name, d in read_lp(scratch.write("dirs.lp", data)):
            if not (np.isfinite(d).all() and abs(np.linalg.norm(d) - 1.0) < 1e-6):
                raise AssertionError(f"read_lp returned a direction that is not a unit vector: {d}")

    return Target("lp", "read_lp (RTI light positions)", seeds, run, caps="file <= 1 MiB")


def _envmap_target(work: Path, scratch: Scratch) -> Target:
    from relight.service.codec import load_uploaded_environment

    seeds = seed_envmaps(work)
    kinds = {b"#?": ".hdr", b"v/": ".exr", b"\x89P": ".png"}

    def run(data: bytes) -> None:
        suffix = kinds.get(data[:2], ".hdr")
        env = load_uploaded_environment(data, suffix)
        if not (np.isfinite(env).all() and env.min() >= 0 and env.shape[1] == 2 * env.shape[0]):
            raise AssertionError("an accepted environment is not a finite non-negative 2:1 map")

    def structured(st):
        sizes = st.sampled_from(((16384, 8192), (8192, 4096), (4096, 2048), (2 ** 31 - 1, 1), (1, 2 ** 31 - 1),
                                 (0, 0), (65536, 65536), (64, 32)))
        return st.tuples(st.sampled_from(seeds), sizes, st.floats(0.0, 1.0)).map(
            lambda a: resize_header(a[0], *a[1])[:max(64, int(len(a[0]) * a[2]))])

    return Target("envmap", "PUT /v1/environment's loader (.hdr/.exr/.png via OpenImageIO)", seeds, run, structured,
                  caps="64 MiB body; 16384x8192 px; OpenImageIO refuses headers claiming far more than the file holds")


def resize_header(data: bytes, w: int, h: int) -> bytes:
    """An image file whose header claims ``w`` x ``h`` pixels (PNG's IHDR with its CRC made right,
    Radiance's resolution line, OpenEXR's data and display windows); the payload as it was."""
    import struct

    if data[:8] == b"\x89PNG\r\n\x1a\n":
        body = bytearray(data)
        body[16:24] = struct.pack(">II", w & 0xFFFFFFFF, h & 0xFFFFFFFF)
        body[29:33] = struct.pack(">I", zlib.crc32(bytes(body[12:29])))
        return bytes(body)
    if data[:2] == b"#?":
        return re.sub(rb"-Y \d+ \+X \d+", f"-Y {h} +X {w}".encode(), data, count=1)
    if data[:4] == b"v/1\x01":
        body = bytearray(data)
        for name in (b"dataWindow\x00box2i\x00", b"displayWindow\x00box2i\x00"):
            i = body.find(name)
            if i >= 0:
                j = i + len(name) + 4
                body[j:j + 16] = struct.pack("<iiii", 0, 0, (w - 1) & 0x7FFFFFFF, (h - 1) & 0x7FFFFFFF)
        return bytes(body)
    return data


def _frame_target(work: Path, scratch: Scratch) -> Target:
    from relight.service.codec import MAX_PIXELS, decode_frame

    seeds = seed_frames(work)

    def run(data: bytes) -> None:
        ctype = "image/png" if data[:4] == b"\x89PNG" else "image/jpeg"
        rgb = decode_frame(data, ctype, MAX_PIXELS)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise AssertionError(f"decode_frame returned {rgb.dtype} {rgb.shape}")

    return Target("frame", "POST /v1/relight's image decoder (PNG/JPEG)", seeds, run,
                  caps="3840x2160 pixels (header checked before decoding)")


def _control_target(work: Path, scratch: Scratch) -> Target:
    from relight.service.controls import apply_control, new_settings, parse_control

    seeds = [json.dumps(d).encode() for d in (
        {"env": "sunset"}, {"rotation": [10, -5, 2]}, {"strength": 0.8, "mode": "paste"}, {"exposure": -1.5},
        {"env": "window", "rotation": [0, 0, 0], "strength": 1, "mode": "transfer", "exposure": 0},
        {"stats": True}, {"tag": 17})]

    def run(data: bytes) -> None:
        text = data.decode("utf-8", errors="replace")
        settings = new_settings()
        before = dict(settings)
        doc = parse_control(text)
        try:
            apply_control(settings, doc)
        except Exception:
            if settings != before:
                raise AssertionError("a refused control changed the settings") from None
            raise

    def structured(st):
        keys = st.sampled_from(("env", "rotation", "strength", "mode", "exposure", "stats", "tag", "x"))
        leaf = st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20)
        value = st.recursive(leaf, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=5), c,
                                                                                          max_size=3), max_leaves=8)
        doc = st.dictionaries(keys, value, max_size=5) | value
        deep = st.integers(1, 100_000).map(lambda n: ("[" * n + "]" * n).encode())
        return doc.map(lambda d: json.dumps(d).encode()) | deep

    return Target("control", "websocket / data channel control messages (JSON)", seeds, run, structured,
                  caps="4096 bytes per message")


def _video_target(work: Path, scratch: Scratch) -> Target:
    from relight.video_read import MAX_VIDEO_DIM, probe_video, read_frames

    seeds = seed_videos(work)
    ext = {b"ftypisom": ".mp4", b"ftypqt  ": ".mov"}

    def run(data: bytes) -> None:
        suffix = ext.get(data[4:12], ".webm")
        p = scratch.write("v" + suffix, data)
        info = probe_video(p)
        for i, rgb in enumerate(read_frames(p, max_frames=3)):
            if rgb.dtype != np.uint8 or rgb.shape != (info.height, info.width, 3):
                raise AssertionError(f"frame {i}: {rgb.dtype} {rgb.shape}, probe said {info}")
            if i == 2:
                break

    return Target("video", "probe_video + first frames (MP4 H.264, MOV HEVC HDR portrait, WebM VP9)", seeds, run,
                  caps=f"{MAX_VIDEO_DIM} px per side; decode stops at 3 frames here")


TARGETS = {"bundle": _bundle_target, "lp": _lp_target, "envmap": _envmap_target, "frame": _frame_target,
           "control": _control_target, "video": _video_target}
