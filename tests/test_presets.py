"""Lighting presets (``builtin:overcast`` ... ``ring-light``, :mod:`relight.presets`) and
``relight presets``' contact sheet."""

from __future__ import annotations

import numpy as np
import pytest

from relight import load_environment
from relight.colour import LUMINANCE
from relight.envmap import builtin_names
from relight.presets import PRESETS

from .lights import white_reading


@pytest.mark.parametrize("name", list(PRESETS))
def test_presets_are_valid_maps_and_named_builtins(name):
    env = load_environment(f"builtin:{name}")
    assert env.shape == (256, 512, 3) and env.dtype == np.float32 and np.isfinite(env).all() and env.min() >= 0
    assert name in builtin_names()
    front = white_reading(env, [0, 0, 1])
    assert 0.2 < front < 3.0, front  # a face toward the camera is lit, in flash units


def test_presets_light_from_where_they_say():
    right, left, up, down, front, back = [1, 0, 0.3], [-1, 0, 0.3], [0, 1, 0.3], [0, -1, 0.3], [0, 0, 1], [0, 0, -1]
    gold = load_environment("builtin:golden-hour")
    assert white_reading(gold, right) > 3 * white_reading(gold, left)  # the sun to the image's right
    sky = load_environment("builtin:overcast")
    assert white_reading(sky, up) > 3 * white_reading(sky, down)
    office = load_environment("builtin:office")
    assert white_reading(office, up) > white_reading(office, down)
    assert white_reading(office, left) > white_reading(office, right)
    stage = load_environment("builtin:stage")
    assert white_reading(stage, up) > 10 * white_reading(stage, down) and white_reading(stage, back) > 0.3
    ring = load_environment("builtin:ring-light")
    assert white_reading(ring, front) > 5 * white_reading(ring, back)
    assert white_reading(ring, right) == pytest.approx(white_reading(ring, left), rel=0.02)  # around the lens
    # the ring's centre is dark: the light comes from a ring, not a disc
    from relight.directions import equirect_directions

    d = equirect_directions(512, 256)
    lum = ring @ LUMINANCE
    centre = lum[d[..., 2] > np.cos(np.radians(4))].mean()
    on_ring = lum[(d[..., 2] < np.cos(np.radians(11))) & (d[..., 2] > np.cos(np.radians(13)))].mean()
    assert on_ring > 20 * centre


def test_gold_is_warm_and_overcast_is_cool():
    def rb(name):
        e = load_environment(f"builtin:{name}").reshape(-1, 3).sum(axis=0)
        return e[0] / e[2]

    assert rb("golden-hour") > 1.5 > rb("overcast") and rb("overcast") < 1.0


def test_the_presets_command_writes_a_labelled_sheet(small_bundle, tmp_path):
    import cv2

    from relight.cli import main
    from relight.cli.presets import SHEET_LIGHTS

    out = tmp_path / "sheet.png"
    assert main(["presets", "--bundle", str(small_bundle.path), "-o", str(out), "--tile", "96", "--columns", "4"]) == 0
    sheet = cv2.imread(str(out), cv2.IMREAD_COLOR)
    label_h = max(18, 96 // 9)
    rows = -(-len(SHEET_LIGHTS) // 4)
    assert sheet.shape == (rows * (96 + label_h), 4 * 96, 3)
    tiles = [sheet[r * (96 + label_h): r * (96 + label_h) + 96, c * 96:(c + 1) * 96]
             for r in range(rows) for c in range(4)][: len(SHEET_LIGHTS)]
    means = [t.reshape(-1, 3).mean(axis=0) for t in tiles]
    assert all(m.max() > 20 for m in means)  # a lit face in every tile
    gold, office = means[SHEET_LIGHTS.index("golden-hour")], means[SHEET_LIGHTS.index("office")]
    assert gold[2] / gold[0] > office[2] / office[0]  # BGR: golden hour's face is the redder
    for bad in (["--tile", "8"], ["--columns", "0"]):
        assert main(["presets", "--bundle", str(small_bundle.path), "-o", str(out), *bad]) != 0
    assert main(["presets", "--bundle", str(small_bundle.path), "-o", str(tmp_path / "sheet.txt")]) != 0
