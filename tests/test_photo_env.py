"""Any picture as the light (``photo:PATH``, :mod:`relight.photo_env`): where its light comes
from, its colour, its highlights, its size and orientation, and hostile files."""

from __future__ import annotations

import numpy as np
import pytest

from relight import load_environment
from relight.colour import LUMINANCE, linear_to_srgb
from relight.errors import InputError
from relight.photo_env import MID_READING, photo_environment

from .lights import white_reading


def _save(path, linear: np.ndarray, orientation: int | None = None, quality: int = 95):
    """A photo (linear RGB) written as an sRGB JPEG or PNG by Pillow (another writer than ours),
    with an EXIF orientation tag when asked."""
    from PIL import Image

    im = Image.fromarray((linear_to_srgb(linear) * 255 + 0.5).astype(np.uint8))
    kw = {"quality": quality} if str(path).endswith(".jpg") else {}
    if orientation is not None:
        exif = im.getexif()
        exif[0x0112] = orientation
        kw["exif"] = exif
    im.save(path, **kw)
    return path


def _left_bright(h=300, w=400) -> np.ndarray:
    photo = np.full((h, w, 3), 0.04, np.float32)
    photo[:, : w // 2] = 0.5
    return photo


def test_the_bright_side_of_a_photo_lights_from_that_side():
    env = photo_environment(_left_bright())
    assert env.shape == (256, 512, 3) and env.dtype == np.float32 and np.isfinite(env).all() and env.min() >= 0
    left, right = white_reading(env, [-1, 0, 0.5]), white_reading(env, [1, 0, 0.5])
    assert left > 3 * right, (left, right)
    up = np.full((300, 400, 3), 0.04, np.float32)
    up[:150] = 0.5  # a bright sky: light from above
    env = photo_environment(up)
    assert white_reading(env, [0, 1, 0.5]) > 3 * white_reading(env, [0, -1, 0.5])


def test_exposure_follows_the_photos_brightness_within_its_range():
    """A mid-grey photo makes a white surface facing the camera read MID_READING flashes; a
    brighter photo reads more, a darker one less (by the square root), a black one still lights."""
    grey = {v: white_reading(photo_environment(np.full((40, 60, 3), v, np.float32)), [0, 0, 1])
            for v in (0.0, 0.02, 0.18, 0.5)}
    assert grey[0.18] == pytest.approx(MID_READING, rel=1e-3)
    assert grey[0.02] < grey[0.18] < grey[0.5]
    assert grey[0.5] == pytest.approx(MID_READING * np.sqrt(0.5 / 0.18), rel=1e-3)
    assert grey[0.0] > 0


def test_clipped_highlights_are_expanded():
    """A clipped window outshines a white-ish wall after the expansion: more than its 8-bit
    value says (the mean radiance ratio of window to wall beyond 1 / 0.8)."""
    photo = np.full((300, 400, 3), 0.6, np.float32)
    photo[60:140, 260:340] = 1.0  # the window, clipped
    env = photo_environment(photo)
    lum = env @ LUMINANCE
    assert lum.max() > 5 * np.median(lum), (lum.max(), np.median(lum))
    plain = photo_environment(np.minimum(photo, 0.6))
    assert np.isclose(plain.max(), np.median(plain), rtol=1e-3)  # nothing clipped: nothing expanded


@pytest.fixture(scope="module")
def face(small_bundle):
    from relight.kernels.relighter import Relighter

    r = Relighter(small_bundle)
    return (lambda source: np.asarray(r.relight(load_environment(source)), dtype=np.float64)), small_bundle.mask


def test_a_photo_bright_on_its_left_lights_the_face_from_the_left(face, tmp_path):
    relight, mask = face
    cols = np.nonzero(mask.any(axis=0))[0]
    right = np.arange(mask.shape[1])[None, :] > (cols.min() + cols.max()) / 2
    lum = relight(f"photo:{_save(tmp_path / 'left.jpg', _left_bright())}") @ LUMINANCE
    assert lum[mask & ~right].mean() > 1.3 * lum[mask & right].mean()


def test_a_warm_photo_gives_a_warmer_face_than_a_cool_one(face, tmp_path):
    relight, mask = face
    rb = {}
    for name, colour in (("warm", (0.5, 0.3, 0.12)), ("cool", (0.12, 0.3, 0.5))):
        photo = np.full((200, 300, 3), colour, np.float32)
        rgb = relight(f"photo:{_save(tmp_path / f'{name}.png', photo)}")[mask].sum(axis=0)
        rb[name] = rgb[0] / rgb[2]
    assert rb["warm"] > 2 * rb["cool"], rb


@pytest.mark.parametrize("orientation", [3, 6, 8])
def test_exif_orientation_is_honoured(tmp_path, orientation):
    """A phone photo stored sideways with its orientation tag makes the environment the upright
    photo makes (the pixels stored turned the other way, as a camera does)."""
    upright = _left_bright(240, 360)
    undo = {3: lambda a: np.rot90(a, 2), 6: lambda a: np.rot90(a, 1), 8: lambda a: np.rot90(a, -1)}[orientation]
    stored = np.ascontiguousarray(undo(upright))
    a = load_environment(f"photo:{_save(tmp_path / 'up.png', upright)}")
    b = load_environment(f"photo:{_save(tmp_path / 'tagged.jpg', stored, orientation, quality=98)}")
    assert np.abs(a - b).max() < 0.02 * a.max()
    c = load_environment(f"photo:{_save(tmp_path / 'untagged.jpg', stored, quality=98)}")
    assert np.abs(a - c).max() > 0.2 * a.max()  # the tag is what made them the same


def test_exif_orientation_matches_pillow_for_all_eight(tmp_path):
    from PIL import Image, ImageOps

    from relight.imageio import read_image

    rng = np.random.default_rng(0)
    blocks = np.kron((rng.random((5, 7, 3)) * 255).astype(np.uint8), np.ones((8, 8, 1), np.uint8))
    for o in range(1, 9):
        im = Image.fromarray(blocks)
        exif = im.getexif()
        exif[0x0112] = o
        im.save(tmp_path / f"o{o}.jpg", exif=exif, quality=98)
        want = np.asarray(ImageOps.exif_transpose(Image.open(tmp_path / f"o{o}.jpg")).convert("RGB")) / 255.0
        got = read_image(tmp_path / f"o{o}.jpg", orient=True, linearize=False)
        assert got.shape == want.shape and np.abs(got - want).max() < 1e-6, o
        assert read_image(tmp_path / f"o{o}.jpg", linearize=False).shape[:2] == blocks.shape[:2]  # maps: as stored


def test_a_large_photo_needs_no_user_step(tmp_path):
    photo = np.tile(np.linspace(0.05, 0.8, 4000, dtype=np.float32)[None, :, None], (3000, 1, 3))
    env = load_environment(f"photo:{_save(tmp_path / 'big.jpg', photo)}")
    assert env.shape == (256, 512, 3) and np.isfinite(env).all()
    assert load_environment(f"photo:{tmp_path / 'big.jpg'}", width=128).shape == (64, 128, 3)


def test_hostile_and_wrong_photos_are_refused_with_a_reason(tmp_path):
    good = _save(tmp_path / "good.jpg", _left_bright())
    data = good.read_bytes()
    (tmp_path / "truncated.jpg").write_bytes(data[: len(data) // 3])
    (tmp_path / "text.jpg").write_bytes(b"not a picture at all" * 10)
    (tmp_path / "empty.jpg").write_bytes(b"")
    for name in ("truncated.jpg", "text.jpg", "empty.jpg", "missing.jpg"):
        with pytest.raises(InputError):
            load_environment(f"photo:{tmp_path / name}")
    with pytest.raises(InputError, match="photo:beach.jpg"):
        load_environment("photo:")
    # without photo: a plain picture must still be a 2:1 lat-long map (a square probe is no photo)
    with pytest.raises(InputError, match="2:1|twice"):
        load_environment(good)


def test_a_photos_header_claiming_too_many_pixels_is_refused_before_decoding(tmp_path):
    from relight.bench.fuzz_targets import resize_header  # the fuzzer's (PNG's IHDR with its CRC made right)
    from relight.photo_env import MAX_PHOTO_PIXELS

    small = _save(tmp_path / "small.png", np.full((8, 8, 3), 0.3, np.float32))
    big = tmp_path / "big.png"
    big.write_bytes(resize_header(small.read_bytes(), 8192, 8192))
    assert 8192 * 8192 > MAX_PHOTO_PIXELS
    with pytest.raises(InputError, match="downscale"):
        load_environment(f"photo:{big}")
