"""Lights saved by name (``NAME.json``, :mod:`relight.saved_light`): written atomically, given back
by ``--env NAME.json`` turned and exposed as saved, and refused when broken or hostile."""

from __future__ import annotations

import json

import numpy as np
import pytest

from relight import load_environment
from relight.directions import rotation_matrix
from relight.envmap import rotate_environment
from relight.errors import InputError
from relight.saved_light import MAX_BYTES, light_document, read_light, save_light


def test_a_saved_light_comes_back_turned_and_exposed(tmp_path):
    doc = light_document("builtin:key:az=-40,kelvin=3200", turn=90, exposure=1.0)
    path = save_light(tmp_path / "lights", "warm-key", doc)
    assert path == tmp_path / "lights" / "warm-key.json" and read_light(path) == doc
    got = load_environment(path)
    want = rotate_environment(load_environment("builtin:key:az=-40,kelvin=3200"), rotation_matrix(90, 0, 0)) * 2
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)
    assert not list((tmp_path / "lights").glob(".*"))  # no temporary file left


def test_a_saved_photo_is_found_beside_the_light(tmp_path):
    from PIL import Image

    (tmp_path / "uploads").mkdir()
    photo = np.full((60, 80, 3), 50, np.uint8)
    photo[:, :40] = 220
    Image.fromarray(photo).save(tmp_path / "uploads" / "beach.jpg")
    path = save_light(tmp_path, "beach", light_document("photo:uploads/beach.jpg"))
    a = load_environment(path)
    b = load_environment(f"photo:{tmp_path / 'uploads' / 'beach.jpg'}")
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("content, says", [
    ("not json", "not JSON"),
    ("[1, 2]", "not a saved light"),
    (json.dumps({"relight_light": 2, "env": "builtin:studio"}), "not a saved light"),
    (json.dumps({"relight_light": 1}), "env"),
    (json.dumps({"relight_light": 1, "env": "other.json"}), "another saved light"),
    (json.dumps({"relight_light": 1, "env": "builtin:studio", "turn": 1e9}), "turn"),
    (json.dumps({"relight_light": 1, "env": "builtin:studio", "exposure": "bright"}), "exposure"),
    ("[" * 10000, "not JSON"),  # nested deeper than the parser goes
])
def test_broken_or_hostile_lights_are_refused(tmp_path, content, says):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(InputError, match=says):
        load_environment(path)


def test_oversized_files_and_bad_names_are_refused(tmp_path):
    big = tmp_path / "big.json"
    big.write_text(" " * (MAX_BYTES + 1))
    with pytest.raises(InputError, match="bytes"):
        read_light(big)
    for name in ("../up", "", ".hidden", "a/b", "x" * 65):
        with pytest.raises(InputError, match="light name"):
            save_light(tmp_path, name, light_document("builtin:studio"))
    with pytest.raises(InputError, match="turn"):
        light_document("builtin:studio", turn=float("nan"))
