import numpy as np
import pytest

from relight.errors import InputError, NumericalError
from relight.imageio import atomic_path, probe_image, read_image, write_image


def test_write_is_atomic_and_keeps_the_old_file(tmp_path):
    target = tmp_path / "a.exr"
    good = np.ones((4, 8, 3), np.float32)
    write_image(target, good)
    before = target.read_bytes()
    bad = good.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(NumericalError):
        write_image(target, bad)
    assert target.read_bytes() == before
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("killed mid-write")
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr"]  # no temporary left behind


def test_identical_data_gives_identical_bytes(tmp_path):
    img = np.random.default_rng(0).uniform(0, 2, (16, 32, 3)).astype(np.float32)
    a = write_image(tmp_path / "a.exr", img).read_bytes()
    b = write_image(tmp_path / "b.exr", img).read_bytes()
    assert a == b


def test_grey_and_rgba_become_rgb(tmp_path):
    write_image(tmp_path / "g.exr", np.full((4, 6), 0.5, np.float32))
    g = read_image(tmp_path / "g.exr")
    assert g.shape == (4, 6, 3) and (g == 0.5).all()
    write_image(tmp_path / "rgba.png", np.zeros((4, 6, 4), np.uint8))
    assert read_image(tmp_path / "rgba.png").shape == (4, 6, 3)
    info = probe_image(tmp_path / "rgba.png")
    assert (info.width, info.height, info.channels, info.linear) == (6, 4, 4, False)


def test_bad_requests(tmp_path):
    with pytest.raises(InputError, match="extension"):
        write_image(tmp_path / "x.bmpx", np.zeros((2, 2, 3), np.float32))
    with pytest.raises(InputError, match="expected"):
        write_image(tmp_path / "x.png", np.zeros((2, 2, 7), np.float32))
    with pytest.raises(InputError, match="limit"):
        write_image(tmp_path / "big.png", np.zeros((4, 40, 3), np.uint8))
        read_image(tmp_path / "big.png", max_dim=16)
