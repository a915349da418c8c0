import numpy as np
import pytest

from relight.errors import InputError
from relight.video import VideoWriter, probe_video, read_frames


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
    assert abs(diff.mean()) < 0.1 and np.abs(diff).mean() < 0.6  # colour conversion only


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
