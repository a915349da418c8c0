"""The environment's turn and spin (``--env-turn``, ``--env-spin``, the stream's ``spin``): one
convention with the HTTP API's rotation and ``rotate_environment``, and how it relates to
turning the head (``render --rotate``)."""

from __future__ import annotations

import numpy as np
import pytest

from relight import load_environment
from relight.directions import rotation_matrix
from relight.envmap import rotate_environment
from relight.errors import InputError

from .tolerances import ENV_TURN_FRAME_CODES


def test_a_turn_moves_a_light_toward_the_images_right():
    """+D degrees moves every light D degrees in azimuth toward +X: a light ahead (+Z) turned by
    90 is at +X (what rotate_environment(env, rotation_matrix(90, 0, 0)) does)."""
    from relight.directions import equirect_directions

    env = load_environment("builtin:point:0,0,1", width=128)
    turned = rotate_environment(env, rotation_matrix(90, 0, 0))
    v, u = np.unravel_index(np.argmax(turned.sum(axis=2)), turned.shape[:2])
    assert equirect_directions(128, 64)[v, u] @ np.array([1.0, 0.0, 0.0]) > 0.99


@pytest.mark.parametrize("region", ["person", "face"])
def test_a_frame_paths_turn_is_the_environment_turned(small_bundle, clip, region):
    """FramePath(env_turn=90) relights as FramePath given the environment turned by 90 degrees
    (a quarter turn is an exact column shift of the map): the same frames within a few codes
    (the texel light is splatted from the rotated directions instead of the shifted map)."""
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    _, frames = clip
    env = load_environment("builtin:window")
    turned = rotate_environment(env, rotation_matrix(90, 0, 0))
    a = FramePath(small_bundle, env, FrameSettings(region=region, env_turn=90))
    b = FramePath(small_bundle, turned, FrameSettings(region=region))
    unturned = FramePath(small_bundle, env, FrameSettings(region=region))
    worst, moved = 0.0, 0.0
    for i, f in enumerate(frames[:8]):
        oa, ia = a.process(f, i / 30)
        ob, ib = b.process(f, i / 30)
        ou, _ = unturned.process(f, i / 30)
        assert ia.face and ib.face
        worst = max(worst, float(np.quantile(np.abs(oa.astype(int) - ob).max(axis=2), 0.999)))
        moved = max(moved, float(np.abs(oa.astype(int) - ou).max()))
    assert worst <= ENV_TURN_FRAME_CODES, worst
    assert moved > 10 * ENV_TURN_FRAME_CODES  # the turn did change the light


def test_spin_counts_from_the_first_frame_and_wraps(small_bundle):
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    fp = FramePath(small_bundle, load_environment("builtin:studio"), FrameSettings(env_turn=10, env_spin=90))
    np.testing.assert_allclose(fp.env_rotation(100.0), rotation_matrix(10, 0, 0), atol=1e-12)  # t0 = 100
    np.testing.assert_allclose(fp.env_rotation(101.0), rotation_matrix(100, 0, 0), atol=1e-12)
    np.testing.assert_allclose(fp.env_rotation(104.0), rotation_matrix(10 + 360, 0, 0), atol=1e-9)
    fp.set_env_spin(0.0)
    fp.set_env_turn(0.0)
    assert fp.env_rotation(5.0) is None  # not turned: nothing composed
    for bad in (float("nan"), 400.0):
        with pytest.raises(InputError, match="turn"):
            fp.set_env_turn(bad)
    with pytest.raises(InputError, match="spin"):
        fp.set_env_spin(1e3)


def test_render_env_turn_is_the_head_turned_the_other_way(small_bundle, tmp_path):
    """`render --env-turn D` gives what `render --rotate -D,0,0` gives (the same rotation)."""
    from relight.cli import main
    from relight.imageio import read_image

    base = ["render", str(small_bundle.path), "--env", "builtin:studio", "-o"]
    assert main([*base, str(tmp_path / "a.exr"), "--env-turn", "35"]) == 0
    assert main([*base, str(tmp_path / "b.exr"), "--rotate", "-35,0,0"]) == 0
    assert main([*base, str(tmp_path / "c.exr")]) == 0
    a, b, c = (read_image(tmp_path / f"{k}.exr") for k in "abc")
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    assert np.abs(a - c).max() > 0.05
    for args in (["--env-turn", "500"], ["--env-turn", "nan"]):
        assert main([*base, str(tmp_path / "d.exr"), *args]) != 0


def test_a_moved_key_keeps_the_locked_exposure_and_a_new_light_matches_anew(small_bundle, clip):
    """relight live's page moving a key light keeps mode transfer's locked exposure (the face
    darkens as the key goes to its side, as it would) and has the person's maps remade when
    next due; another environment is matched anew."""
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    _, frames = clip
    fp = FramePath(small_bundle, load_environment("builtin:key:az=0"), FrameSettings(region="person"))
    for i, f in enumerate(frames[:30]):
        fp.process(f, i / 30)
    lock = fp.live_light.exposure_lock
    assert lock.lock is not None and fp.person.last is not None  # locked by now, the maps made
    fp.set_environment(load_environment("builtin:key:az=60"), moved=True)
    assert fp.live_light.exposure_lock is lock and lock.lock is not None
    assert fp.person.last is not None  # kept to serve until remade
    out, info = fp.process(frames[30], 1.0)
    assert info.face and "person" in info.ran  # remade in the next frame (not a live source: in it)
    fp.set_environment(load_environment("builtin:sunset"))
    assert fp.live_light.exposure_lock is not lock and fp.live_light.exposure_lock.lock is None
    assert fp.person.last is None


def test_a_moved_light_is_a_draft_until_it_settles(small_bundle, clip):
    """While a light is moved (a key dragged) the face is relit from the low-rank part alone - no
    exact texel row is made - within DRAFT_REL of the full relight; settle() relights in full."""
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    from .tolerances import DRAFT_REL

    _, frames = clip
    fp = FramePath(small_bundle, load_environment("builtin:key:az=-30,size=10"), FrameSettings(region="face"))
    for i, f in enumerate(frames[:5]):
        fp.process(f, i / 30)
    cache = fp.relighter.row_cache
    assert cache is not None  # a recipe bundle: rows are made on demand
    cache.stop_prefetch()
    made = cache.made
    fp.set_environment(load_environment("builtin:key:az=40,size=10"), moved=True)
    assert fp.draft
    fp.process(frames[5], 5 / 30)
    fp.relighter.sync()
    draft = fp.relit_frame.copy()
    assert cache.made == made  # no row made for the moved light
    fp.settle()
    assert not fp.draft
    fp.process(frames[5], 5 / 30)
    fp.relighter.sync()
    full = fp.relit_frame.copy()
    assert cache.made > made  # its brightest texels' rows, now
    assert 0 < np.linalg.norm(draft - full) / np.linalg.norm(full) < DRAFT_REL
