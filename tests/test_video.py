import numpy as np
import pytest

from relight.errors import InputError
from relight.video_read import probe_video, read_frames
from relight.video_write import VideoWriter

from .tolerances import VIDEO_BIAS_CODES, VIDEO_MEAN_CODES, YUV_FAST_MEAN_CODES, YUV_FAST_ROUNDTRIP_CODES


def _smooth_frames(n=6, size=(160, 96)):
    w, h = size
    y, x = np.mgrid[0:h, 0:w]
    out = []
    for i in range(n):
        r = 40 + 150 * (x / w)
        g = 60 + 120 * (y / h) + 10 * np.sin(x / 9.0 + i)
        b = 90 + 60 * np.cos(y / 13.0)
        out.append(np.stack([r, g, b], axis=-1).round().astype(np.uint8))
    return out


def test_round_trip_is_unbiased(tmp_path):
    frames = _smooth_frames()
    with VideoWriter(tmp_path / "v.mp4", 30, (160, 96), crf=0) as w:
        for f in frames:
            w.write(f)
    info = probe_video(tmp_path / "v.mp4")
    assert (info.width, info.height, round(info.fps)) == (160, 96, 30)
    back = list(read_frames(tmp_path / "v.mp4"))
    assert len(back) == len(frames)
    diff = np.stack(back).astype(float) - np.stack(frames)
    assert abs(diff.mean()) < VIDEO_BIAS_CODES and np.abs(diff).mean() < VIDEO_MEAN_CODES  # colour conversion only


def test_the_planes_conversions_follow_swscale_and_are_unbiased():
    """relight.video_yuv's Y'CbCr <-> RGB (OpenCV's vector paths, for the boxes the per-frame path
    touches) against swscale's exact settings (what players and relight.video_frame use), on a real
    photo: close on average, unbiased, and a round trip as faithful as 4:2:0 allows."""
    from skimage import data

    from relight.video_write import to_yuv
    from relight.video_yuv import YuvFrame, planes_to_rgb, rgb_to_planes

    rgb = np.ascontiguousarray(data.astronaut()[:, :510])
    h, w = rgb.shape[:2]
    flat, n = to_yuv(rgb).to_ndarray().reshape(-1), h * w
    y = flat[:n].reshape(h, w)
    u, v = flat[n:n + n // 4].reshape(h // 2, w // 2), flat[n + n // 4:].reshape(h // 2, w // 2)
    d = planes_to_rgb(y, u, v).astype(float) - YuvFrame(y, u, v).to_rgb()
    assert abs(d.mean()) < VIDEO_BIAS_CODES and np.abs(d).mean() < YUV_FAST_MEAN_CODES
    for ours, theirs in zip(rgb_to_planes(rgb), (y, u, v), strict=True):
        d = ours.astype(float) - theirs
        assert abs(d.mean()) < VIDEO_BIAS_CODES and np.abs(d).mean() < YUV_FAST_MEAN_CODES
    d = planes_to_rgb(*rgb_to_planes(rgb)).astype(float) - rgb
    assert abs(d.mean()) < VIDEO_BIAS_CODES and np.abs(d).mean() < YUV_FAST_ROUNDTRIP_CODES
    flat = np.full((4, 6, 3), 200, np.uint8)  # a flat colour comes back as it was
    assert np.abs(planes_to_rgb(*rgb_to_planes(flat)).astype(int) - 200).max() <= 1


def test_writer_is_atomic(tmp_path):
    target = tmp_path / "v.mp4"
    with pytest.raises(RuntimeError):
        with VideoWriter(target, 30, (160, 96)) as w:
            w.write(_smooth_frames(1)[0])
            raise RuntimeError("killed")
    assert not target.exists() and list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="even"):
        VideoWriter(target, 30, (161, 96))


def test_broken_videos(tmp_path):
    with VideoWriter(tmp_path / "v.mp4", 30, (160, 96)) as w:
        for f in _smooth_frames(30):
            w.write(f)
    data = (tmp_path / "v.mp4").read_bytes()
    (tmp_path / "cut.mp4").write_bytes(data[: len(data) // 3])
    with pytest.raises(InputError):
        list(read_frames(tmp_path / "cut.mp4"))
    (tmp_path / "junk.mp4").write_bytes(b"not a video" * 100)
    with pytest.raises(InputError):
        probe_video(tmp_path / "junk.mp4")
    with pytest.raises(InputError, match="no such"):
        probe_video(tmp_path / "missing.mp4")
    with pytest.raises(InputError, match="more than"):
        list(read_frames(tmp_path / "v.mp4", max_frames=5))


@pytest.mark.parametrize("degrees,hflip,vflip", [(0, False, False), (90, False, False), (180, False, False),
                                                 (270, False, False), (0, True, False), (0, False, True),
                                                 (90, True, False), (90, False, True)])
def test_display_orientation_follows_the_container_matrix(tmp_path, degrees, hflip, vflip):
    """Every EXIF orientation written as PyAV documents it (rotate counter-clockwise, then mirror)
    reads back as the turn and mirror that show the frame that way."""
    import av

    from relight.video_orient import display_orientation, orient

    coded = np.zeros((48, 64, 3), np.uint8)
    coded[:16, :16] = 255  # a bright corner: top left
    coded[-16:, :16, 0] = 255  # a red one: bottom left
    path = tmp_path / "o.mp4"
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        s.set_display_rotation(degrees, hflip=hflip, vflip=vflip)
        for pkt in s.encode(av.VideoFrame.from_ndarray(coded, format="rgb24")):
            c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    want = np.rot90(coded, degrees // 90)
    want = want[:, ::-1] if hflip else want
    want = want[::-1] if vflip else want
    with av.open(str(path)) as c:
        frame = next(iter(c.decode(c.streams.video[0])))
    turns, mirror = display_orientation(frame)
    shown = orient(frame.to_ndarray(format="rgb24"), turns, mirror)
    assert shown.shape == want.shape
    assert np.abs(shown.astype(int) - want.astype(int)).mean() < 8  # H.264 ringing at the corners' edges


@pytest.mark.parametrize("degrees,hflip", [(90, False), (270, False), (180, True)])
def test_turned_video_reads_upright_in_every_reader(tmp_path, degrees, hflip):
    """A portrait video stored as turned frames plus a display matrix: probe, full frames, luma
    and crops (the capture's path) all see it as displayed."""
    import av

    from relight.video_frame import crop_frame, frame_to_rgb
    from relight.video_read import probe_video, read_frames, read_frames_raw, read_luma

    rng = np.random.default_rng(5)
    shown = cv2_resize_noise(rng, (96, 64))  # displayed: 64 wide, 96 high (portrait)
    coded = np.rot90(shown[:, ::-1] if hflip else shown, -(degrees // 90))  # what the phone stores
    path = tmp_path / "portrait.mp4"
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = coded.shape[1], coded.shape[0], "yuv444p"
        s.options = {"crf": "0"}
        s.set_display_rotation(degrees, hflip=hflip)
        for _ in range(3):
            for pkt in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(coded), format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    info = probe_video(path)
    assert (info.width, info.height) == (64, 96)
    frames = list(read_frames(path))
    assert frames[0].shape == shown.shape and np.abs(frames[0].astype(int) - shown).mean() < 3
    luma = next(iter(read_luma(path)))
    assert luma.shape == shown.shape[:2]
    raw = next(iter(read_frames_raw(path)))
    full = frame_to_rgb(raw)
    box = (10, 20, 30, 40)
    crop = crop_frame(raw, box)
    assert crop.shape == (40, 30) and crop.luma().shape == (40, 30)
    assert np.abs(crop.rgb().astype(int) - full[20:60, 10:40]).mean() < 3


def cv2_resize_noise(rng, shape):
    """Smooth random colour (no edges that 4:2:0 or the codec would blur), uint8 (H, W, 3)."""
    import cv2

    small = rng.uniform(30, 225, size=(shape[0] // 8, shape[1] // 8, 3)).astype(np.float32)
    return cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)


def test_decoded_frames_do_not_outlive_their_use(tmp_path, monkeypatch):
    """Reading a frame's display matrix ties the frame and its side data in a reference cycle;
    the decode loops collect them (release_frames), so a long decode holds only a few frames -
    not every frame since the last full collection (a 4K capture's ingest held ~190, 2.9 GB)."""
    import gc

    import av

    import relight.video_read as video

    frames = _smooth_frames(n=60)
    with VideoWriter(tmp_path / "v.mp4", 30, (160, 96)) as w:
        for f in frames:
            w.write(f)
    gc.collect()
    gc.disable()  # only release_frames may collect
    try:
        monkeypatch.setattr(video, "RELEASE_BYTES", 8 * 160 * 96 * 3 // 2)  # every 8 frames here
        for f in video.read_frames_raw(tmp_path / "v.mp4"):
            video.display_orientation(f)  # reads the side data: the cycle
        alive = sum(isinstance(o, av.VideoFrame) for o in gc.get_objects())
    finally:
        gc.enable()
    assert alive <= 10, f"{alive} decoded frames still alive"


@pytest.mark.slow  # capture, filter and live in processes (~10 s): `make test-slow`, CI
def test_frames_with_side_data_pyav_cannot_name_are_read(frame, small_bundle, tmp_path, capsys):
    """A PNG relight writes (OpenImageIO adds an eXIf chunk: FFmpeg 8's EXIF side data, type 31,
    which PyAV 18's Type enum lacks, as it lacks multi-view HEVC's 28-30) named as a video: the
    probe, the readers, capture, filter and live read it - no traceback; capture says it is one
    frame; a file that is no video at all is refused the same clear way."""
    import subprocess
    import sys

    import av

    from relight.imageio import write_image

    png = write_image(tmp_path / "still.png", frame)
    clip = tmp_path / "still.mp4"
    clip.write_bytes(png.read_bytes())
    with av.open(str(clip)) as c:  # the case itself: PyAV refuses to list this frame's side data
        first = next(c.decode(video=0))
        with pytest.raises(ValueError, match="not a valid Type"):
            list(first.side_data)
    info = probe_video(clip)
    assert (info.width, info.height) == (frame.shape[1], frame.shape[0])
    (back,) = list(read_frames(clip))
    np.testing.assert_array_equal(back, frame)  # PNG: lossless
    from relight.cli import main

    assert main(["capture", str(clip), "-o", str(tmp_path / "b.bundle"), "--quiet"]) == 2
    assert "1 frames" in capsys.readouterr().err
    assert main(["filter", str(clip), str(tmp_path / "out.mp4"), "--bundle", str(small_bundle.path), "--env",
                 "builtin:window", "--focal", "ortho", "--quiet"]) == 0
    assert len(list(read_frames(tmp_path / "out.mp4"))) == 1
    # live in its own process (signals, threads), as a user runs it
    r = subprocess.run([sys.executable, "-m", "relight", "live", "--bundle", str(small_bundle.path), "--env",
                        "builtin:window", "--camera", str(clip), "--focal", "ortho", "--duration", "1",
                        "--record", str(tmp_path / "live.mp4")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert len(list(read_frames(tmp_path / "live.mp4"))) >= 1
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    for args in (["capture", str(junk), "-o", str(tmp_path / "j.bundle"), "--quiet"],
                 ["filter", str(junk), str(tmp_path / "j.mp4"), "--bundle", str(small_bundle.path), "--env",
                  "builtin:window", "--quiet"]):
        assert main(args) == 2
        assert "not a readable video" in capsys.readouterr().err
