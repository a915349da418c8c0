"""The seed files of ``relight bench fuzz``: real files from ``../shared/data`` (the Yale faces,
the RTI dome's photos and light positions, the HDR light probes) and files the product makes
from them (a bundle captured from a real face, clips of real face photos); without
``../shared`` the synthetic studio's."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from .real_data import shared_data


def real_face_frames(n: int, size: tuple[int, int]) -> list[np.ndarray]:
    """``n`` real face photos (Yale B01) as (h, w, 3) uint8, or the synthetic studio's head."""
    import cv2

    shared = shared_data()
    if shared is not None:
        files = sorted((shared / "faces-yale" / "yaleB01").glob("*.png"))[:n]
        imgs = [cv2.imread(str(f), cv2.IMREAD_COLOR) for f in files]
    else:  # the synthetic studio's head (a live clip's first frames)
        from relight.pipeline.synth.live_clip import LiveConfig, synthesize_live
        from relight.video_read import read_frames

        folder = Path(tempfile.mkdtemp(prefix="relight-fuzz-live-"))
        try:
            synthesize_live(folder, LiveConfig(width=160, height=90, duration=1.0, seed=3, audio="none"),
                            progress=False)
            imgs = [f[..., ::-1] for f, _ in zip(read_frames(folder / "live.mp4"), range(n), strict=False)]
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    return [np.ascontiguousarray(cv2.resize(im, size, interpolation=cv2.INTER_AREA)[..., ::-1]) for im in imgs]


def seed_bundle(work: Path) -> bytes:
    path = work / "seed.bundle"
    if not path.exists():
        from relight.pipeline.capture import capture

        shared = shared_data()
        if shared is not None:
            from .accuracy_real import scaled_rti
            src = scaled_rti(shared / "faces-yale" / "yaleB01", work / "yale4", 4)
            capture(src, path, images=True, progress=False)
        else:  # the synthetic studio's
            from relight.pipeline.synth.config import SynthConfig
            from relight.pipeline.synth.studio import synthesize
            res = synthesize(work / "studio", SynthConfig(width=320, height=180, duration=6.0, seed=3), progress=False)
            capture(res.video, path, progress=False)
    return path.read_bytes()


def seed_lp(work: Path) -> list[bytes]:
    shared = shared_data()
    if shared is not None:
        return [(shared / "rti-dome" / d / "dirs.lp").read_bytes() for d in ("Dome", "Test")]
    rng = np.random.default_rng(0)
    d = rng.normal(size=(12, 3))
    d[:, 2] = np.abs(d[:, 2])
    return [("12\n" + "".join(f"image{i:02d}.jpg {x:.6f} {y:.6f} {z:.6f}\n" for i, (x, y, z) in enumerate(d))).encode()]


def seed_envmaps(work: Path) -> list[bytes]:
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


def seed_frames(work: Path) -> list[bytes]:
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


def seed_videos(work: Path) -> list[bytes]:
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
    seed_bundle(folder), seed_videos(folder), seed_envmaps(folder)
