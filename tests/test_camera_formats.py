"""A camera in its own format (issue 48): NV12 and YUYV (a USB webcam's and a virtual camera's raw
formats) and MJPEG (full-range 4:2:2 JPEG frames) are kept in their Y'CbCr planes - read as their
RGB is, relit there by ``relight live`` with no RGB round trip of the frame, and recorded."""

from __future__ import annotations

import io
import sys

import numpy as np
import pytest

from .tolerances import CAMERA_FORMAT_CODES

#: The formats, and what the decoder gives for each (MJPEG decodes to full-range planes).
FORMATS = {"nv12": ("rawvideo", "nv12", "nv12"), "yuyv422": ("rawvideo", "yuyv422", "yuyv422"),
           "mjpeg": ("mjpeg", "yuvj422p", "yuvj422p")}


def _camera_clip(src, folder, fmt: str):
    """``src``'s first 45 frames re-written as a camera in ``fmt`` would deliver them."""
    import av

    from relight.video_read import read_frames

    codec, pix_fmt, _ = FORMATS[fmt]
    path = folder / f"camera-{fmt}.{'mkv' if codec == 'mjpeg' else 'nut'}"
    frames = list(read_frames(src))[:45]
    h, w = frames[0].shape[:2]
    with av.open(str(path), "w") as out:
        st = out.add_stream(codec, rate=30)
        st.width, st.height, st.pix_fmt = w, h, pix_fmt
        if codec == "mjpeg":
            st.options = {"q:v": "3"}
        for f in frames:
            vf = av.VideoFrame.from_ndarray(f, format="rgb24").reformat(format=pix_fmt)
            for packet in st.encode(vf):
                out.mux(packet)
        for packet in st.encode():
            out.mux(packet)
    return path


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_camera_in_its_own_format_is_relit_in_its_planes(small_bundle, live_clip, tmp_path, fmt):
    from relight.apps.live import run_live
    from relight.apps.live_status import StatusLine
    from relight.video_frame import frame_to_rgb
    from relight.video_read import probe_video, read_frames, read_frames_raw
    from relight.video_yuv import YuvFrame

    clip = _camera_clip(live_clip, tmp_path, fmt)
    decoded = next(iter(read_frames_raw(clip)))
    assert decoded.format.name == FORMATS[fmt][2]
    kept = YuvFrame.from_av(decoded)
    assert kept is not None  # kept in its planes
    d = np.abs(kept.to_rgb().astype(int) - frame_to_rgb(decoded))
    assert d.mean() < CAMERA_FORMAT_CODES  # read as its RGB is
    rec = tmp_path / "rec.mp4"
    switch = sys.getswitchinterval()
    res = run_live(small_bundle, ["builtin:sunset"], camera=str(clip), duration=3.0, focal="ortho", record=rec,
                   status=StatusLine(io.StringIO()))
    assert sys.getswitchinterval() == switch  # (shortened while the frames ran: restored)
    assert res.camera_format == FORMATS[fmt][2]
    assert res.frames_in > 20 and res.frames_in_planes == res.frames_in  # every frame kept in its planes
    assert res.frames_relit > 10 and res.faces >= 0.8 * res.frames_relit
    out = list(read_frames(rec))
    assert len(out) == res.frames_out and probe_video(rec).width == decoded.width
    src = list(read_frames(clip))
    changed = [np.abs(o.astype(int) - src[0]).max(axis=2) > 8 for o in out[-5:]]
    assert all(c.sum() > 200 for c in changed)  # relit (the head moves a little: more than that changes)
