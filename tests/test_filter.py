"""The per-frame video path on frames (relit on the face, untouched elsewhere; frames kept in
their planes) and the `relight filter` command."""

import json

import cv2
import numpy as np
import pytest

from relight import load_environment
from relight.cli import main
from relight.errors import InputError
from relight.video_read import read_frames
from relight.video_write import VideoWriter

from .tolerances import (
    OFF_PERSON_CODES,
    OFF_PERSON_MEAN_CODES,
    PIPELINE_VS_SERIAL_CODES,
    RELIT_SHARE,
    STILL_HEAD_DEG,
    STILL_HEAD_RESIZED_DEG,
    TIMESTAMP_S,
    WHOLE_PERSON_SHARE,
    YUV_GREY_CODES,
    YUV_RELIT_MEAN_CODES,
    YUV_RELIT_PERSON_MEAN_CODES,
    YUV_SMALL_MEAN_CODES,
)


def test_a_frame_kept_in_its_planes_is_relit_in_them(clip, small_bundle):
    """The Y'CbCr path (relight.video_yuv): the tracker's grey and a small copy as the RGB path
    makes them, and a frame relit in its planes as through RGB - with every pixel off what was
    relit bit for bit the decoder's - the face alone and the whole person."""
    import av

    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings
    from relight.video_frame import frame_to_rgb
    from relight.video_yuv import YuvFrame

    path, _ = clip
    with av.open(str(path)) as c:
        decoded = [f for _, f in zip(range(12), c.decode(video=0), strict=False)]
    yf = [YuvFrame.from_av(f) for f in decoded]
    assert all(y is not None for y in yf)  # our writer's H.264: 8-bit BT.709 limited range
    rgb = [frame_to_rgb(f) for f in decoded]
    h, w = rgb[0].shape[:2]
    grey = cv2.resize(cv2.cvtColor(rgb[0], cv2.COLOR_RGB2GRAY), (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    assert np.abs(yf[0].tracking_grey((w // 2, h // 2)).astype(int) - grey).max() <= YUV_GREY_CODES
    assert np.array_equal(yf[0].to_av().to_ndarray(format="yuv420p")[:h], yf[0].y)
    small = yf[0].small_rgb((w // 2, h // 2))
    d = np.abs(small.astype(int) - cv2.resize(rgb[0], (w // 2, h // 2), interpolation=cv2.INTER_AREA))
    assert d.mean() < YUV_SMALL_MEAN_CODES
    for region in ("face", "person"):
        # (the studio's frames are orthographic: told so, as every test of a path on them)
        fp = FramePath(small_bundle, load_environment("builtin:sunset"), FrameSettings(region=region, focal="ortho"))
        a = [fp.process(f, i / 30) for i, f in enumerate(rgb)]
        fp.reset()
        b = [fp.process(f, i / 30) for i, f in enumerate(yf)]
        assert sum(i.face for _, i in b) == sum(i.face for _, i in a) > 6
        for (ra, _), (yb, ib), src, yin in zip(a, b, rgb, yf, strict=True):
            assert isinstance(yb, YuvFrame)
            if not ib.face:
                continue
            changed = (ra != src).any(axis=2) | (yb.y != yin.y)
            bound = YUV_RELIT_MEAN_CODES if region == "face" else YUV_RELIT_PERSON_MEAN_CODES
            assert changed.sum() > 300 and np.abs(yb.to_rgb().astype(int) - ra)[changed].mean() < bound
            assert np.array_equal(yb.y[~changed], yin.y[~changed])


def test_frames_are_relit_on_the_face_and_untouched_elsewhere(frame_path, small_bundle, clip):
    _, frames = clip
    frame_path.reset()
    # The capture's head moves a few pixels at most: the changes must stay on the reference's head.
    head = cv2.dilate(np.asarray(small_bundle.mask, np.uint8), np.ones((15, 15), np.uint8)) > 0
    found = 0
    for i, f in enumerate(frames[:30]):
        out, info = frame_path.process(f, i / 30)
        found += info.face
        if info.face:
            assert max(abs(a) for a in info.angles) < STILL_HEAD_DEG  # and barely turns
            changed = np.abs(out.astype(int) - f.astype(int)).sum(axis=2) > 3
            assert changed.sum() > RELIT_SHARE * small_bundle.mask.sum()  # the face took the new light
            assert not (changed & ~head).any()
    assert found >= 28


def test_the_whole_person_relit_stays_on_the_person(small_bundle, small_capture, clip):
    """region="person": the light's change reaches past the face (neck, hair) and stays on the
    person - the studio's head and neck at the reference pose, grown by the capture's motion -
    even where the segmentation model sees shoulders on the wall (this clip's cartoon head has
    none)."""
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings
    from relight.imageio import read_image

    _, frames = clip
    res, _ = small_capture
    person = read_image(res.truth / "mask.png")[..., 0] > 0.5
    grown = cv2.dilate(person.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    env = load_environment("builtin:sunset")
    whole = FramePath(small_bundle, env, FrameSettings(region="person"))
    face_only = FramePath(small_bundle, env, FrameSettings(region="face"))
    more = []
    for i, f in enumerate(frames[:20]):
        out, info = whole.process(f, i / 30)
        ref, _ = face_only.process(f, i / 30)
        if not info.face:
            continue
        diff = np.abs(out.astype(int) - f.astype(int))
        changed = diff.sum(axis=2) > 3
        # off the person: issue 32's goals - a stray pixel of the matte at most (mean change and
        # 99.9th percentile in codes), never a ghost
        off = diff.max(axis=2)[~grown]
        assert off.mean() <= OFF_PERSON_MEAN_CODES and np.percentile(off, 99.9) <= OFF_PERSON_CODES
        more.append(changed.sum() / max((np.abs(ref.astype(int) - f.astype(int)).sum(axis=2) > 3).sum(), 1))
    assert len(more) >= 18 and np.median(more) > WHOLE_PERSON_SHARE


def test_the_rigid_grid_covers_the_composited_face_with_a_cell_to_spare(small_bundle):
    """The warp is defined inside the hull of its control points and evaluated on cells of
    GRID_STEP px: every reference pixel the face's alpha reaches lies a cell inside that hull in
    every direction (a grid that stopped at the crop's edge left an unrelit band on tight crops)."""
    from scipy.spatial import Delaunay

    from relight.engine.frame_path import FramePath
    from relight.engine.warp import GRID_STEP
    from relight.kernels.compositor import ALPHA_FLOOR

    env = load_environment("builtin:studio")
    for fp in (FramePath(small_bundle, env),):
        ctrl = np.concatenate([fp.rig.control_ref[:fp.rig.n_landmarks], fp.rig.grid_ref])
        tri = Delaunay(ctrl)
        ay, ax = np.nonzero(fp.rig.alpha_crop > ALPHA_FLOOR)
        pts = np.stack([ax, ay], axis=1).astype(np.float64) + np.asarray(fp.rig.origin, np.float64)
        for dx, dy in ((GRID_STEP, 0), (-GRID_STEP, 0), (0, GRID_STEP), (0, -GRID_STEP)):
            assert (tri.find_simplex(pts + [dx, dy]) >= 0).all(), (fp.rig.grid_step, dx, dy)


def test_strength_zero_and_faceless_frames_pass_through(small_bundle, clip):
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    _, frames = clip
    fp = FramePath(small_bundle, load_environment("builtin:studio"), FrameSettings(strength=0.0, mode="paste"))
    out, info = fp.process(frames[3], 0.0)
    assert info.face and np.array_equal(out, frames[3])
    blank = np.full_like(frames[0], 90)
    out, info = fp.process(blank, 1.0)
    assert not info.face and np.array_equal(out, blank) and info.note
    with pytest.raises(InputError, match="strength"):
        fp.set_strength(1.5)
    with pytest.raises(InputError, match="mode"):
        fp.set_mode("glow")
    with pytest.raises(InputError, match="uint8"):
        fp.process(frames[0].astype(np.float32), 0.0)


def _streams(path):
    import av

    with av.open(str(path)) as c:
        v = c.streams.video[0]
        pts = [f.pts for f in c.decode(v)]
    with av.open(str(path)) as c:
        audio = [s.codec_context.name for s in c.streams.audio]
    return pts, audio


def test_filter_command_keeps_audio_timestamps_and_reports(small_bundle, clip, tmp_path, capsys):
    path, frames = clip
    out = tmp_path / "relit.mp4"
    rc = main(["filter", str(path), str(out), "--bundle", str(small_bundle.path), "--env", "builtin:window",
               "--report", str(tmp_path / "rep"), "--quiet"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "median" in printed and "p99" in printed
    pts_in, audio_in = _streams(path)
    pts_out, audio_out = _streams(out)
    assert pts_out == pts_in and audio_out == audio_in == ["aac"]
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert rep["frames"] == len(frames) and rep["faces"] >= len(frames) - 3
    assert all(k.isdigit() and len(v) == 3 for k, v in rep["head_rotation"].items())
    assert rep["timings_ms"]["total"]["p99"] > 0
    relit = list(read_frames(out))
    assert len(relit) == len(frames)


def test_pipelined_filter_is_repeatable_and_close_to_the_serial_path(small_bundle, clip, tmp_path):
    """relight filter runs the per-frame path in two stages on two threads (front of frame N+1
    beside back of frame N): two runs give the same frames, and they stay within a few codes of
    the serial FramePath.process (the tracker takes the live-lit reference one frame later)."""
    from relight.apps.filter import run_filter
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    path, frames = clip
    env = load_environment("builtin:sunset")
    runs = []
    for k in range(2):
        out = tmp_path / f"p{k}.mp4"
        res = run_filter(path, out, small_bundle, env, progress=False, crf=0, focal="ortho")
        assert res.frames == len(frames)
        runs.append(list(read_frames(out)))
    assert all(np.array_equal(a, b) for a, b in zip(*runs, strict=True))
    fp = FramePath(small_bundle, env, FrameSettings(focal="ortho"))
    serial = [fp.process(f, i / 30.0)[0] for i, f in enumerate(frames)]
    # crf 0: lossless but in YUV 4:2:0 - compare through the same encode
    ser_path = tmp_path / "serial.mp4"
    with VideoWriter(ser_path, 30.0, (frames[0].shape[1], frames[0].shape[0]), crf=0) as wr:
        for f in serial:
            wr.write(f)
    diff = [np.abs(a.astype(int) - b.astype(int)).mean() for a, b in zip(runs[0], read_frames(ser_path), strict=True)]
    assert max(diff) < PIPELINE_VS_SERIAL_CODES


def test_filter_preset_is_checked_and_used(small_bundle, clip, tmp_path):
    """--preset picks the H.264 encoder's settings (realtime by default: x264's ultrafast with
    CABAC, B-frames and deblocking); a preset x264 lacks is refused with the list, before any
    frame is read."""
    from relight.apps.filter import run_filter
    from relight.video_write import DEFAULT_PRESET, X264_PRESETS, check_preset

    assert DEFAULT_PRESET == "realtime" and check_preset("medium") == "medium"
    with pytest.raises(InputError, match="realtime, ultrafast"):
        check_preset("turbo")
    path, frames = clip
    env = load_environment("builtin:studio")
    with pytest.raises(InputError, match="preset 'turbo'"):
        run_filter(path, tmp_path / "x.mp4", small_bundle, env, progress=False, preset="turbo")
    assert not (tmp_path / "x.mp4").exists()
    with pytest.raises(SystemExit):
        main(["filter", str(path), str(tmp_path / "y.mp4"), "--bundle", str(small_bundle.path), "--env",
              "builtin:studio", "--preset", "turbo"])
    out = tmp_path / "s.mp4"
    assert main(["filter", str(path), str(out), "--bundle", str(small_bundle.path), "--env", "builtin:studio",
                 "--mode", "paste", "--preset", X264_PRESETS[1], "--quiet"]) == 0
    assert len(list(read_frames(out))) == len(frames)


def test_filter_reads_image_sequences_and_writes_png_folders(small_bundle, clip, tmp_path):
    from relight.imageio import write_image

    _, frames = clip
    seq = tmp_path / "seq"
    seq.mkdir()
    for i, f in enumerate(frames[:6]):
        write_image(seq / f"f{i:03d}.png", f)
    out = tmp_path / "out_frames"
    assert main(["filter", str(seq), str(out), "--bundle", str(small_bundle.path), "--env", "builtin:studio",
                 "--mode", "paste", "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [f"{i:06d}.png" for i in range(6)]


def test_filter_writes_a_video_as_png_frames_without_a_second_encode(small_bundle, clip, tmp_path):
    """A video into a folder (no suffix, or an empty folder): its frames as PNGs, each the
    pipelined path's frame exactly (what the live frame's benchmark measures); the audio is
    left out and the report says so; a folder with files in it is refused, nothing written."""
    from relight.apps.filter import run_filter

    path, frames = clip
    env = load_environment("builtin:sunset")
    out = tmp_path / "frames"
    res = run_filter(path, out, small_bundle, env, progress=False)
    assert res.frames == len(frames) and res.audio.startswith("left out")
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"{i:06d}.png" for i in range(len(frames))]
    video = tmp_path / "v.mp4"
    run_filter(path, video, small_bundle, env, progress=False, crf=0)
    first = cv2.imread(str(out / names[0]))[..., ::-1]
    # the PNG frames differ from the lossless video's only by its 4:2:0 YUV round trip
    assert np.abs(first.astype(int) - next(iter(read_frames(video))).astype(int)).mean() < PIPELINE_VS_SERIAL_CODES
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="not an empty folder"):
        run_filter(path, full, small_bundle, env, progress=False)
    assert [p.name for p in full.iterdir()] == ["keep.txt"]


def test_filter_bad_input_fails_cleanly_and_leaves_no_output(small_bundle, clip, tmp_path, capsys):
    path, frames = clip
    bundle = str(small_bundle.path)
    truncated = tmp_path / "truncated.mp4"
    truncated.write_bytes(path.read_bytes()[:2000])
    garbage = tmp_path / "garbage.mp4"
    garbage.write_bytes(b"\x00" * 5000)
    for bad in (truncated, garbage, tmp_path / "missing.mp4"):
        out = tmp_path / f"out_{bad.stem}.mp4"
        assert main(["filter", str(bad), str(out), "--bundle", bundle, "--env", "builtin:studio", "--quiet"]) == 2
        assert not out.exists()
        assert list(tmp_path.glob(f".out_{bad.stem}*")) == []
        assert "error" in capsys.readouterr().err
    assert main(["filter", str(path), str(path), "--bundle", bundle, "--env", "builtin:studio", "--quiet"]) == 2
    # A video without a face: a valid output, frames unchanged, and a note saying so.
    faceless = tmp_path / "faceless.mp4"
    with VideoWriter(faceless, 30, (frames[0].shape[1], frames[0].shape[0])) as wr:
        for i in range(5):
            wr.write(np.full_like(frames[0], 40 + 10 * i))
    out = tmp_path / "faceless_out.mp4"
    assert main(["filter", str(faceless), str(out), "--bundle", bundle, "--env", "builtin:studio", "--quiet"]) == 0
    assert "no face" in capsys.readouterr().out
    a, b = list(read_frames(faceless)), list(read_frames(out))
    assert len(a) == len(b) == 5
    assert all(np.abs(x.astype(int) - y.astype(int)).max() <= 2 for x, y in zip(a, b, strict=True))


def test_filter_keeps_variable_frame_rate_timestamps(small_bundle, clip, tmp_path):
    import av

    _, frames = clip
    src = tmp_path / "vfr.mkv"
    pts = [0, 1, 3, 4, 7, 8, 9, 12, 13, 16]  # gaps: a variable frame rate, time base 1/30 s
    with av.open(str(src), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
        s.time_base = s.codec_context.time_base = __import__("fractions").Fraction(1, 30)
        for p, f in zip(pts, frames, strict=False):
            vf = av.VideoFrame.from_ndarray(f, format="rgb24").reformat(format="yuv420p")
            vf.pts = p
            for pk in s.encode(vf):
                c.mux(pk)
        for pk in s.encode(None):
            c.mux(pk)
    out = tmp_path / "vfr_out.mkv"
    assert main(["filter", str(src), str(out), "--bundle", str(small_bundle.path), "--env", "builtin:studio",
                 "--quiet"]) == 0

    def times(path):
        with av.open(str(path)) as c:
            v = c.streams.video[0]
            return [float(f.pts * v.time_base) for f in c.decode(v)]

    assert np.allclose(times(out), times(src), atol=TIMESTAMP_S)
    assert np.allclose(np.diff(times(src)), np.diff(pts) / 30.0, atol=TIMESTAMP_S)


def test_virtual_camera_without_the_extra_says_how_to_install_it(small_bundle, clip, tmp_path, capsys):
    try:
        import pyvirtualcam  # noqa: F401
        pytest.skip("pyvirtualcam is installed: the message for its absence cannot be checked")
    except ImportError:
        pass
    path, _ = clip
    out = tmp_path / "vc.mp4"
    assert main(["filter", str(path), str(out), "--bundle", str(small_bundle.path), "--env", "builtin:studio",
                 "--virtual-camera", "--quiet"]) == 2
    assert "pyvirtualcam" in capsys.readouterr().err and not out.exists()


def test_frames_of_another_size_than_the_bundle_are_relit(small_bundle, clip):
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    _, frames = clip
    # (the studio's camera)
    fp = FramePath(small_bundle, load_environment("builtin:studio"), FrameSettings(focal="ortho"))
    found = 0
    for i, f in enumerate(frames[:12]):
        big = cv2.resize(f, (f.shape[1] * 3 // 2, f.shape[0] * 3 // 2), interpolation=cv2.INTER_LINEAR)
        out, info = fp.process(big, i / 30)
        assert out.shape == big.shape
        found += info.face
        if info.face:
            assert max(abs(a) for a in info.angles) < STILL_HEAD_RESIZED_DEG
    assert found >= 10
