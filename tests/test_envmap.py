import struct
import zlib

import numpy as np
import pytest

from relight import load_environment
from relight.colour import luminance
from relight.directions import direction_to_equirect_uv, equirect_solid_angles, rotation_matrix
from relight.envmap import (
    BUILTINS,
    environment_stem,
    environment_to_lights,
    grid_cell_directions,
    rotate_environment,
    validate_environment,
)
from relight.errors import InputError
from relight.imageio import write_image

from .tolerances import F32_CLOSE, F32_EXACT, F64_CLOSE, ROTATE_ROUND_TRIP_REL, ROTATED_POWER_REL, TEXEL_POSITION


def _power(env):
    h, w = env.shape[:2]
    return (env.astype(np.float64) * equirect_solid_angles(w, h)[:, None, None]).sum(axis=(0, 1))


@pytest.mark.parametrize("name", ["studio", "sunset", "window", "uniform", "room"])
def test_builtins_are_valid_maps(name):
    env = load_environment(f"builtin:{name}")
    assert env.shape == (256, 512, 3) and env.dtype == np.float32
    assert np.isfinite(env).all() and (env >= 0).all()
    assert load_environment(f"builtin:{name}", width=128).shape == (64, 128, 3)


def test_sunset_dynamic_range():
    lum = luminance(load_environment("builtin:sunset"))
    assert lum.max() / lum.min() >= 1e4


def test_point_light_lands_where_the_convention_says():
    # +X lands at a quarter of the width, +Z at the centre, +Y on the top row.
    for d, (col, row) in {(1, 0, 0): (128, 128), (0, 0, 1): (256, 128), (0, 1, 0): (None, 0)}.items():
        env = load_environment(f"builtin:point:{d[0]},{d[1]},{d[2]}")
        r, c = np.unravel_index(np.argmax(luminance(env)), env.shape[:2])
        assert abs(r - row) <= 2
        if col is not None:
            assert abs(c - col) <= 2 or abs(c + 1 - col) <= 2


def test_point_light_is_as_strong_as_a_flash():
    # Radiance integrates to pi: a white Lambertian surface facing it reads 1.
    np.testing.assert_allclose(_power(load_environment("builtin:point:0.3,0.2,1")), np.pi, rtol=F32_EXACT)
    np.testing.assert_allclose(_power(load_environment("builtin:uniform")), 4 * np.pi, rtol=F32_EXACT)


@pytest.mark.parametrize("bad", ["builtin:nope", "builtin:point:1,2", "builtin:point:a,b,c", "builtin:point:0,0,0"])
def test_bad_builtins_say_what_to_write(bad):
    with pytest.raises(InputError, match=r"builtin|point|choose"):
        load_environment(bad)


def test_stems():
    assert environment_stem("builtin:studio") == "studio"
    assert environment_stem("/x/y/grace.hdr") == "grace"
    assert environment_stem("builtin:point:1,0,0") == "point_1_0_0"


@pytest.mark.parametrize("ext", [".exr", ".hdr", ".png", ".jpg"])
def test_files_round_trip(tmp_path, ext):
    env = load_environment("builtin:window", width=64)
    if ext in (".png", ".jpg"):
        env = np.clip(env, 0, 1)
    path = write_image(tmp_path / f"env{ext}", env)
    back = load_environment(path)
    assert back.shape == env.shape and back.dtype == np.float32
    # JPEG is lossy (chroma subsampling smears the window's edges); the others are not.
    tol = {".exr": 1e-7, ".hdr": 0.02, ".png": 0.01, ".jpg": 0.1}[ext]
    assert np.abs(back - env).max() <= tol * max(1.0, float(env.max()))


def test_ldr_files_are_decoded_from_srgb(tmp_path):
    grey = np.full((8, 16, 3), 128, dtype=np.uint8)
    write_image(tmp_path / "g.png", grey)
    assert load_environment(tmp_path / "g.png")[0, 0, 0] == pytest.approx(0.2158605, abs=F32_CLOSE)


def test_not_two_to_one(tmp_path):
    write_image(tmp_path / "sq.exr", np.ones((32, 32, 3), np.float32))
    with pytest.raises(InputError, match="twice as wide"):
        load_environment(tmp_path / "sq.exr")


def _raw_exr(path, data):
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(data.shape[1], data.shape[0], 3, "float"))
    out.write_image(np.ascontiguousarray(data, dtype=np.float32))
    out.close()


def test_nan_and_negative_radiance(tmp_path):
    env = np.ones((16, 32, 3), np.float32)
    env[3, 4, 1] = np.nan
    _raw_exr(tmp_path / "nan.exr", env)
    with pytest.raises(InputError, match="non-finite"):
        load_environment(tmp_path / "nan.exr")
    env[3, 4, 1] = -2.0
    _raw_exr(tmp_path / "neg.exr", env)
    with pytest.raises(InputError, match="negative"):
        load_environment(tmp_path / "neg.exr")
    with pytest.raises(InputError, match="non-finite"):
        validate_environment(np.full((4, 8, 3), np.inf))


@pytest.mark.parametrize("ext", [".exr", ".hdr", ".png"])
def test_truncated_files(tmp_path, ext):
    env = np.random.default_rng(0).uniform(0, 1, (64, 128, 3)).astype(np.float32)
    path = write_image(tmp_path / f"t{ext}", env)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError):
        load_environment(path)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png_header_only(width, height):
    """A PNG whose header claims width x height but whose pixel data is a few bytes."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", zlib.compress(b"\0" * 16))
            + _png_chunk(b"IEND", b""))


def test_huge_header_dimensions_are_refused_before_decoding(tmp_path):
    png = tmp_path / "huge.png"
    png.write_bytes(_png_header_only(200000, 100000))
    with pytest.raises(InputError, match="limit"):
        load_environment(png)
    hdr = tmp_path / "huge.hdr"
    hdr.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 200000\n" + b"\0" * 64)
    with pytest.raises(InputError):
        load_environment(hdr)


@pytest.mark.parametrize("content", [b"", b"this is not an image at all\n" * 20])
def test_not_images(tmp_path, content):
    p = tmp_path / "x.exr"
    p.write_bytes(content)
    with pytest.raises(InputError):
        load_environment(p)
    with pytest.raises(InputError, match="no such file"):
        load_environment(tmp_path / "missing.hdr")


def test_real_light_probes(shared_data):
    for name in ("grace.hdr", "uffizi.hdr"):
        env = load_environment(shared_data / "envmaps" / name)
        assert env.shape == (128, 256, 3)
        assert np.isfinite(env).all() and env.min() >= 0
    grace = load_environment(shared_data / "envmaps" / "grace.hdr")
    assert grace.max() > 1000 * grace.mean()  # a real high-dynamic-range case


def test_rotation_moves_a_light_where_the_matrix_says():
    d = np.array([0.3, 0.4, 0.866])
    env = load_environment(f"builtin:point:{d[0]},{d[1]},{d[2]}")
    r = rotation_matrix(yaw=37, pitch=-12, roll=20)
    rot = rotate_environment(env, r)
    u, v = direction_to_equirect_uv(r @ (d / np.linalg.norm(d)))
    row, col = np.unravel_index(np.argmax(luminance(rot)), rot.shape[:2])
    assert abs(row + 0.5 - v * 256) <= TEXEL_POSITION and abs(col + 0.5 - u * 512) <= TEXEL_POSITION
    # Power is kept (a 2-degree light is neither lost nor doubled).
    np.testing.assert_allclose(_power(rot), _power(env), rtol=ROTATED_POWER_REL)


def test_rotation_round_trip_and_quarter_turns():
    env = load_environment("builtin:studio")
    r = rotation_matrix(yaw=25, pitch=10, roll=-5)
    back = rotate_environment(rotate_environment(env, r), r.T)
    err = np.abs(back - env).mean() / env.mean()
    assert err < ROTATE_ROUND_TRIP_REL
    quarter = rotate_environment(env, rotation_matrix(yaw=90))
    np.testing.assert_array_equal(rotate_environment(quarter, rotation_matrix(yaw=-90)), env)
    # +Z content moves to +X under a 90-degree yaw.
    np.testing.assert_array_equal(quarter[:, 128], env[:, 256])


@pytest.mark.parametrize("pole", ["y", "z"])
def test_lights_conserve_power_and_share_the_grid(pole):
    for name in BUILTINS:
        env = load_environment(f"builtin:{name}")
        lights = environment_to_lights(env, grid=(128, 64), pole=pole, keep_grid=True)
        np.testing.assert_allclose(lights.power.sum(axis=0), _power(env), rtol=F64_CLOSE)
        np.testing.assert_allclose(lights.dirs[:lights.n_grid], grid_cell_directions(128, 64, pole))
    sun = environment_to_lights(load_environment("builtin:sunset"), pole=pole)
    own = sun.column < 0
    assert 0 < own.sum() < 50  # the sun's texels are lights of their own, the sky is on the grid


def test_camera_grid_columns_are_image_directions():
    from relight.kernels.heightfield import grid_directions

    d = grid_cell_directions(16, 8, "z").reshape(8, 16, 3)
    img = grid_directions(16)
    for col in range(16):
        xy = d[:, col, :2] / np.linalg.norm(d[:, col, :2], axis=1, keepdims=True)
        np.testing.assert_allclose(xy[:, 0], img[col, 0], atol=F32_EXACT)
        np.testing.assert_allclose(-xy[:, 1], img[col, 1], atol=F32_EXACT)
