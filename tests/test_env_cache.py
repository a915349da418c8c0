"""The one cache of loaded environment maps (relight.env_cache), which the service and relight live share."""

import numpy as np
import pytest

from relight.directions import rotation_matrix
from relight.env_cache import TURN_SUPERSAMPLE, EnvironmentCache
from relight.envmap import load_environment, rotate_environment
from relight.errors import InputError


def test_a_map_is_loaded_once_and_turned_as_rotate_environment_turns_it():
    cache = EnvironmentCache(4)
    a = cache.get("builtin:sunset")
    assert cache.get("builtin:sunset") is a  # kept: the same array
    np.testing.assert_array_equal(a, load_environment("builtin:sunset"))
    turned = cache.get("builtin:sunset", (30.0, 0.0, 0.0))
    np.testing.assert_array_equal(turned, rotate_environment(a, rotation_matrix(30.0, 0.0, 0.0),
                                                             supersample=TURN_SUPERSAMPLE))
    assert cache.get("builtin:sunset", (0.0, 0.0, 0.0)) is a  # no turn: the map as it is


def test_the_least_recently_used_go_first_and_pinned_ones_and_uploads_stay():
    cache = EnvironmentCache(2)
    cache.pin(["builtin:studio"])
    cache.get("builtin:studio")
    upload = np.full((8, 16, 3), 0.5, np.float32)
    cache.put("mine", upload)
    for name in ("sunset", "window", "room", "uniform"):
        cache.get(f"builtin:{name}")
    cache.get("builtin:room")  # used again: newer than uniform
    assert "builtin:studio" in cache and "mine" in cache
    assert "builtin:sunset" not in cache and "builtin:window" not in cache
    assert "builtin:room" in cache and "builtin:uniform" in cache
    assert cache.get("mine") is upload
    # a new upload under the same name replaces the map and its turned copies
    turned = cache.get("mine", (10.0, 0.0, 0.0))
    cache.put("mine", upload * 2)
    assert cache.get("mine", (10.0, 0.0, 0.0)) is not turned


def test_a_bad_source_raises_and_keeps_nothing():
    cache = EnvironmentCache(2)
    with pytest.raises(InputError):
        cache.get("builtin:nope")
    assert "builtin:nope" not in cache


def test_the_width_follows_the_source():
    cache = EnvironmentCache(2, width=lambda source: 64 if source.endswith("window") else None)
    assert cache.get("builtin:window").shape[1] == 64
    assert cache.get("builtin:sunset").shape[1] != 64
