"""``relight bench fuzz``: every reader of hostile input, fed mutated real files (Hypothesis).

Targets (each the function a user's file or a client's request reaches first, then what the
product does with what it returned):

* ``bundle`` - :func:`relight.load_bundle`, then every accessor the relighter and the service
  read (background, masks, frame index, room light, recipe, maps of a few pixels). Mutations
  of the raw bytes, and of the JSON header with its checksums made right again (a crafted
  file, not only a damaged one).
* ``lp`` - the RTI light-position parser (:func:`relight.pipeline.capture.read_lp`).
* ``envmap`` - an environment upload (``PUT /v1/environment``), i.e. the file loader behind it
  (.hdr / .exr / .png headers and payloads through OpenImageIO).
* ``frame`` - the image decoder behind ``POST /v1/relight`` (PNG / JPEG).
* ``control`` - the websocket's (and the WebRTC data channel's) JSON control messages.
* ``video`` - the video prober and the first frames' decode (MP4 H.264, MOV HEVC 10-bit
  portrait with HDR tags, WebM VP9).

Seeds are real files: ``../shared/data`` (the Yale faces, the RTI dome's photos and light
positions, the HDR light probes) and files the product makes from them (a bundle captured from
a real face, clips of real face photos); without ``../shared`` the synthetic studio's. A run
counts the inputs tried per target, the outcomes (accepted, refused with our error), crashes
(any other exception: Hypothesis shrinks it and the report prints the smallest input) and the
largest memory one input made us allocate (``tracemalloc`` peak: NumPy's buffers included;
the peak resident set of the target's process as well, which counts native buffers too).
"""

from __future__ import annotations

import json
import re
import resource
import shutil
import tempfile
import time
import tracemalloc
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: Inputs per target: CI's bounded pass, the bench's default; ``--examples`` sets any other.
QUICK_EXAMPLES = 40
DEFAULT_EXAMPLES = 1500
#: Interesting replacement values (header fields, counts, sizes, numbers in text).
INTERESTING_INTS = (0, 1, -1, 2, 3, 7, 16, 64, 255, 256, 4096, 65535, 65536, 2 ** 31 - 1, 2 ** 31, 2 ** 32,
                    2 ** 63 - 1, 10 ** 12)
INTERESTING_TEXT = ("0", "-1", "1e308", "-1e308", "nan", "inf", "-0", "4294967296", "99999999999999999999",
                    "1e-320", "", " ", "\x00", "NaN", "1.5", "0x10")


def shared_data() -> Path | None:
    p = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    return p if p.is_dir() else None


# ---------------------------------------------------------------------------------- mutations

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


def mutations(st):
    """A Hypothesis strategy of byte-level edits: (op, where, value) triples applied in order."""
    ops = st.sampled_from(("flip", "byte", "int32", "insert", "delete", "truncate", "repeat", "splice",
                           "number"))
    return st.lists(st.tuples(ops, st.floats(0.0, 1.0), st.integers(0, 2 ** 32 - 1), st.booleans()),
                    min_size=0, max_size=6)


def apply_mutations(data: bytes, edits, seeds: list[bytes]) -> bytes:
    """``data`` with ``edits`` applied; positions are fractions, biased to the first 512 bytes
    (where the headers a parser trusts live) when the edit's flag is set."""
    buf = bytearray(data)
    for op, frac, value, head in edits:
        n = len(buf)
        span = min(n, 512) if head else n
        pos = min(int(frac * span), max(n - 1, 0))
        if op == "flip" and n:
            buf[pos] ^= 1 << (value % 8)
        elif op == "byte" and n:
            buf[pos] = (0x00, 0xFF, 0x7F, 0x80, 0x01, 0x20, 0x0A)[value % 7] if value & 8 else value & 0xFF
        elif op == "int32" and n >= 4:
            v = INTERESTING_INTS[value % len(INTERESTING_INTS)] & 0xFFFFFFFF
            pos = min(pos, n - 4)
            buf[pos:pos + 4] = v.to_bytes(4, "little" if value & 32 else "big")
        elif op == "insert":
            rng = np.random.default_rng(value)
            buf[pos:pos] = rng.integers(0, 256, 1 + value % 64, dtype=np.uint8).tobytes()
        elif op == "delete" and n:
            del buf[pos:pos + 1 + value % 256]
        elif op == "truncate":
            del buf[pos:]
        elif op == "repeat" and n:
            chunk = bytes(buf[pos:pos + 1 + value % 128])
            buf[pos:pos] = chunk * (1 + value % 4)
        elif op == "splice" and seeds:
            other = seeds[value % len(seeds)]
            cut = int(frac * len(other))
            buf[pos:] = other[cut:]
        elif op == "number":
            nums = list(re.finditer(rb"-?\d+(\.\d+)?([eE][-+]?\d+)?", bytes(buf[:1 << 16])))
            if nums:
                m = nums[value % len(nums)]
                buf[m.start():m.end()] = INTERESTING_TEXT[(value >> 8) % len(INTERESTING_TEXT)].encode()
    return bytes(buf)


# ------------------------------------------------------------------------------------- targets

@dataclass
class Target:
    """One reader under test: ``run(data)`` parses one input and uses what it returned."""

    name: str
    what: str
    seeds: list[bytes]
    run: object  # Callable[[bytes], None]
    structured: object = None  # optional Callable[[st], strategy of bytes] beside the byte edits
    caps: str = ""


def _expected(exc: BaseException) -> bool:
    """Whether ``exc`` is one of the refusals we mean to give (our errors, an HTTP 4xx)."""
    from relight.errors import InputError, NumericalError
    from relight.service.errors import ServiceError

    if isinstance(exc, InputError | NumericalError):
        return True
    return isinstance(exc, ServiceError) and 400 <= exc.status < 500


class _Scratch:
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


def _bundle_target(work: Path, scratch: _Scratch) -> Target:
    from relight import load_bundle

    seed = _seed_bundle(work)

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


def _lp_target(work: Path, scratch: _Scratch) -> Target:
    from relight.pipeline.capture import read_lp

    seeds = _seed_lp(work)

    def run(data: bytes) -> None:
        for _name, d in read_lp(scratch.write("dirs.lp", data)):
            if not (np.isfinite(d).all() and abs(np.linalg.norm(d) - 1.0) < 1e-6):
                raise AssertionError(f"read_lp returned a direction that is not a unit vector: {d}")

    return Target("lp", "read_lp (RTI light positions)", seeds, run, caps="file <= 1 MiB")


def _envmap_target(work: Path, scratch: _Scratch) -> Target:
    from relight.service.codec import load_uploaded_environment

    seeds = _seed_envmaps(work)
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


def _frame_target(work: Path, scratch: _Scratch) -> Target:
    from relight.service.codec import MAX_PIXELS, decode_frame

    seeds = _seed_frames(work)

    def run(data: bytes) -> None:
        ctype = "image/png" if data[:4] == b"\x89PNG" else "image/jpeg"
        rgb = decode_frame(data, ctype, MAX_PIXELS)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise AssertionError(f"decode_frame returned {rgb.dtype} {rgb.shape}")

    return Target("frame", "POST /v1/relight's image decoder (PNG/JPEG)", seeds, run,
                  caps="3840x2160 pixels (header checked before decoding)")


def _control_target(work: Path, scratch: _Scratch) -> Target:
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


def _video_target(work: Path, scratch: _Scratch) -> Target:
    from relight.video import MAX_VIDEO_DIM, probe_video, read_frames

    seeds = _seed_videos(work)
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


# --------------------------------------------------------------------------------------- seeds

def real_face_frames(n: int, size: tuple[int, int]) -> list[np.ndarray]:
    """``n`` real face photos (Yale B01) as (h, w, 3) uint8, or the synthetic studio's head."""
    import cv2

    shared = shared_data()
    if shared is not None:
        files = sorted((shared / "faces-yale" / "yaleB01").glob("*.png"))[:n]
        imgs = [cv2.imread(str(f), cv2.IMREAD_COLOR) for f in files]
    else:  # the synthetic studio's head (a live clip's first frames)
        from relight.pipeline.synth.live import LiveConfig, synthesize_live
        from relight.video import read_frames

        folder = Path(tempfile.mkdtemp(prefix="relight-fuzz-live-"))
        try:
            synthesize_live(folder, LiveConfig(width=160, height=90, duration=1.0, seed=3, audio="none"),
                            progress=False)
            imgs = [f[..., ::-1] for f, _ in zip(read_frames(folder / "live.mp4"), range(n), strict=False)]
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    return [np.ascontiguousarray(cv2.resize(im, size, interpolation=cv2.INTER_AREA)[..., ::-1]) for im in imgs]


def _seed_bundle(work: Path) -> bytes:
    path = work / "seed.bundle"
    if not path.exists():
        from relight.pipeline.capture import capture

        shared = shared_data()
        if shared is not None:
            from .accuracy import scaled_rti
            src = scaled_rti(shared / "faces-yale" / "yaleB01", work / "yale4", 4)
            capture(src, path, images=True, progress=False)
        else:  # the synthetic studio's
            from relight.pipeline.synth.studio import SynthConfig, synthesize
            res = synthesize(work / "studio", SynthConfig(width=320, height=180, duration=6.0, seed=3), progress=False)
            capture(res.video, path, progress=False)
    return path.read_bytes()


def _seed_lp(work: Path) -> list[bytes]:
    shared = shared_data()
    if shared is not None:
        return [(shared / "rti-dome" / d / "dirs.lp").read_bytes() for d in ("Dome", "Test")]
    rng = np.random.default_rng(0)
    d = rng.normal(size=(12, 3))
    d[:, 2] = np.abs(d[:, 2])
    return [("12\n" + "".join(f"image{i:02d}.jpg {x:.6f} {y:.6f} {z:.6f}\n" for i, (x, y, z) in enumerate(d))).encode()]


def _seed_envmaps(work: Path) -> list[bytes]:
    """The real probes as they are (.hdr) and shrunk to 64x32 as .exr, .hdr and .png."""
    import cv2

    from relight import load_environment
    from relight.imageio import write_image

    shared = shared_data()
    sources = sorted((shared / "envmaps").glob("*.hdr")) if shared is not None else []
    out = [p.read_bytes() for p in sources]
    env = load_environment(sources[0]) if sources else load_environment("builtin:sunset", width=64)
    small = cv2.resize(env, (64, 32), interpolation=cv2.INTER_AREA)
    for ext in (".exr", ".hdr", ".png"):
        p = write_image(work / f"seed-env{ext}", small)
        out.append(p.read_bytes())
    return out


def _seed_frames(work: Path) -> list[bytes]:
    """Real photos as the service receives them: Yale faces (PNG) and RTI dome photos (JPEG)."""
    import cv2

    shared = shared_data()
    out = []
    if shared is not None:
        out += [f.read_bytes() for f in sorted((shared / "faces-yale" / "yaleB01").glob("*.png"))[:2]]
        out += [f.read_bytes() for f in sorted((shared / "rti-dome" / "Dome").glob("*.jpg"))[:2]]
    for im in real_face_frames(1, (96, 72)):
        out.append(cv2.imencode(".png", im[..., ::-1])[1].tobytes())
        out.append(cv2.imencode(".jpg", im[..., ::-1], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes())
    return out


def _seed_videos(work: Path) -> list[bytes]:
    """Six real face photos as an MP4 (H.264), a portrait MOV (HEVC 10-bit, PQ/BT.2020 tags,
    rotation 90) and a WebM (VP9)."""
    import av

    frames = real_face_frames(6, (96, 72))
    out = []
    for name, codec, fmt, rot in (("seed.mp4", "libx264", "yuv420p", 0), ("seed.mov", "libx265", "yuv420p10le", 90),
                                  ("seed.webm", "libvpx-vp9", "yuv420p", 0)):
        path = work / name
        if not path.exists():
            with av.open(str(path), "w") as c:
                s = c.add_stream(codec, rate=30)
                s.width, s.height = (72, 96) if rot else (96, 72)
                s.pix_fmt = fmt
                if codec == "libx265":
                    s.options = {"x265-params": "log-level=error"}
                    cc = s.codec_context
                    cc.colorspace, cc.color_primaries, cc.color_trc = 9, 9, 16  # BT.2020, PQ
                if rot:
                    s.set_display_rotation(rot)
                for i, rgb in enumerate(frames):
                    img = np.ascontiguousarray(np.rot90(rgb, -1)) if rot else rgb
                    f = av.VideoFrame.from_ndarray(img, format="rgb24").reformat(format=fmt)
                    f.pts = i
                    for pkt in s.encode(f):
                        c.mux(pkt)
                for pkt in s.encode():
                    c.mux(pkt)
        out.append(path.read_bytes())
    return out


def make_seeds(folder: Path) -> None:
    """Make the seeds that take a while (the bundle, the clips, the environment files) in ``folder``."""
    _seed_bundle(folder), _seed_videos(folder), _seed_envmaps(folder)


# -------------------------------------------------------------------------------------- runner

@dataclass
class Result:
    target: str
    what: str
    caps: str
    inputs: int = 0
    accepted: int = 0
    refused: int = 0
    crashes: int = 0
    crash: str = ""
    seconds: float = 0.0
    peak_traced_mb: float = 0.0
    peak_rss_mb: float = 0.0
    seeds: int = 0
    refusals: dict = field(default_factory=dict)
    # Largest rise of the process's peak resident set on one input (MB): a lower bound of what
    # that input made native code (OpenImageIO, FFmpeg, PoCL) allocate and touch.
    rss_rise_mb: float = 0.0


def fuzz_target(name: str, work: Path, examples: int, seed: int = 0, *, raise_crash: bool = False) -> Result:
    """Fuzz one target with ``examples`` Hypothesis examples; a crash is shrunk and recorded (or
    raised with ``raise_crash``, for tests)."""
    from hypothesis import HealthCheck, Phase, Verbosity, given, settings
    from hypothesis import seed as hseed
    from hypothesis import strategies as st
    from hypothesis.errors import HypothesisWarning

    work.mkdir(parents=True, exist_ok=True)
    scratch = _Scratch(work)
    try:
        target = TARGETS[name](work, scratch)
        res = Result(target=name, what=target.what, caps=target.caps, seeds=len(target.seeds))
        seeds = target.seeds
        byte_inputs = st.tuples(st.sampled_from(seeds), mutations(st)).map(
            lambda se: apply_mutations(se[0], se[1], seeds))
        inputs = byte_inputs | target.structured(st) if target.structured else byte_inputs
        peak = [0]
        rss_high = [resource.getrusage(resource.RUSAGE_SELF).ru_maxrss]

        crash_input = [None]

        def one(data: bytes) -> None:
            res.inputs += 1
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
            try:
                target.run(data)
                res.accepted += 1
            except Exception as exc:  # noqa: BLE001 - sorting refusals from crashes is the point
                if not _expected(exc):
                    crash_input[0] = data  # the last failing input Hypothesis tries is its shrunk one
                    raise
                res.refused += 1
                kind = type(exc).__name__
                res.refusals[kind] = res.refusals.get(kind, 0) + 1
            finally:
                peak[0] = max(peak[0], tracemalloc.get_traced_memory()[1] - base)
                rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                if rss - rss_high[0] > res.rss_rise_mb * 1024:  # the largest rise of the high-water mark
                    res.rss_rise_mb = (rss - rss_high[0]) / 1024
                    (work / f"rss-{name}.bin").write_bytes(data)
                rss_high[0] = max(rss_high[0], rss)

        test = settings(max_examples=examples, deadline=None, database=None, derandomize=False,
                        suppress_health_check=list(HealthCheck), phases=[Phase.generate, Phase.shrink],
                        print_blob=False, verbosity=Verbosity.quiet)(given(inputs)(one))
        test = hseed(seed)(test)
        warnings.filterwarnings("ignore", category=HypothesisWarning)  # "overly large repr" of file-sized inputs
        started = tracemalloc.is_tracing()
        if not started:
            tracemalloc.start()
        t0 = time.perf_counter()
        try:
            test()
        except Exception as exc:  # noqa: BLE001 - the shrunk crash, reported
            res.crashes += 1
            res.crash = f"{type(exc).__name__}: {exc}"[:2000]
            if crash_input[0] is not None:
                kept = work / f"crash-{name}.bin"
                kept.write_bytes(crash_input[0])
                res.crash += f" (input kept in {kept})"
            if raise_crash:
                raise
        finally:
            res.seconds = time.perf_counter() - t0
            if not started:
                tracemalloc.stop()
        res.peak_traced_mb = peak[0] / 2 ** 20
        res.peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        return res
    finally:
        scratch.close()


def _child(name: str, work: str, examples: int, seed: int, queue) -> None:
    try:
        queue.put(fuzz_target(name, Path(work), examples, seed).__dict__)
    except BaseException as exc:  # the child's own failure (seeds, imports): reported as a crash
        queue.put({"target": name, "what": "", "caps": "", "crashes": 1, "crash": f"{type(exc).__name__}: {exc}"})


def run(out: Path, *, targets=None, examples: int = DEFAULT_EXAMPLES, seed: int = 0, progress: bool = True) -> dict:
    """Fuzz each target in its own process (its peak RSS its own); write ``bench.json``."""
    import multiprocessing as mp

    from relight.imageio import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    names = list(targets or TARGETS)
    ctx = mp.get_context("spawn")
    rows = []
    for name in names:
        if progress:
            print(f"fuzz {name}: {examples} inputs ...", flush=True)
        q = ctx.Queue()
        p = ctx.Process(target=_child, args=(name, str(out / "seeds"), examples, seed, q))
        p.start()
        try:
            row = q.get(timeout=max(600.0, examples * 2.0))
        except Exception:  # noqa: BLE001 - the child died without a word: a crash of the process
            row = {"target": name, "what": "", "caps": "", "crashes": 1,
                   "crash": f"the process died (exit code {p.exitcode}); the input it died on is under "
                            f"{out / 'seeds'}/scratch-*"}
        p.join(30)
        if p.exitcode not in (0, None) and not row.get("crash"):
            row.update(crashes=1, crash=f"the process exited with code {p.exitcode}")
        rows.append(row)
        if progress:
            print(f"  {row.get('inputs', 0)} inputs, {row.get('crashes', 0)} crashes, "
                  f"{row.get('seconds', 0):.1f} s", flush=True)
    doc = {"examples": examples, "seed": seed, "real_seeds": shared_data() is not None, "targets": rows}
    with atomic_path(out / "bench.json") as tmp:
        tmp.write_text(json.dumps(doc, indent=2))
    return doc


def table(doc: dict) -> str:
    lines = ["| target | inputs | accepted | refused (our error / 4xx) | crashes | largest allocation of one input "
             "(traced / RSS rise) | time | caps |", "|---|---|---|---|---|---|---|---|"]
    for r in doc["targets"]:
        lines.append(f"| {r['target']} | {r.get('inputs', 0)} | {r.get('accepted', 0)} | {r.get('refused', 0)} | "
                     f"{r.get('crashes', 0)} | {r.get('peak_traced_mb', 0):.1f} / {r.get('rss_rise_mb', 0):.0f} MB | "
                     f"{r.get('seconds', 0):.0f} s | {r.get('caps', '')} |")
    crashes = [r for r in doc["targets"] if r.get("crashes")]
    for r in crashes:
        lines.append(f"\ncrash in {r['target']}: {r['crash']}")
    return "\n".join(lines)

