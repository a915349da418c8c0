"""A frame path's settings: one value, every field checked where it is made."""

import dataclasses

import numpy as np
import pytest

from relight.engine.frame_settings import EXPOSURE_RANGE_EV, FrameSettings
from relight.errors import InputError


@pytest.mark.parametrize("change, words", [
    ({"mode": "glow"}, "mode 'glow': use one of transfer"),
    ({"region": "hands"}, "region 'hands': use one of"),
    ({"strength": 1.5}, "strength 1.5: use a number from 0 to 1"),
    ({"strength": float("nan")}, "strength nan"),
    ({"strength": "full"}, "strength full"),
    ({"exposure": EXPOSURE_RANGE_EV[1] + 1}, "exposure 21.0: use stops (EV)"),
    ({"env_turn": 400.0}, "environment turn 400.0: use degrees"),
    ({"env_spin": np.inf}, "environment spin inf: use degrees per second"),
    ({"reuse_deg": -1.0}, "reuse_deg -1.0: use 0 (always relight) to 5 degrees"),
    ({"field_rows": 8}, "field_rows 8: use a number of rows from 16 to 4320"),
    ({"field_rows": 90.5}, "field_rows 90.5"),
    ({"field_rows": True}, "field_rows True"),
])
def test_a_bad_setting_is_refused_saying_what_to_change(change, words):
    with pytest.raises(InputError) as err:
        FrameSettings(**change)
    assert words in str(err.value)


def test_settings_are_made_plain_numbers_and_frozen():
    s = FrameSettings(strength=np.float32(0.5), exposure=1, field_rows=np.int64(120), live_source=1)
    assert type(s.strength) is float and s.strength == 0.5 and type(s.field_rows) is int and s.live_source is True
    assert s.exposure_gain == 2.0 and not FrameSettings(region="face").whole_head and FrameSettings().whole_head
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.mode = "paste"
    assert dataclasses.replace(s, mode="paste").mode == "paste"
    with pytest.raises(InputError):
        dataclasses.replace(s, strength=2.0)  # a change is checked as a new value is


def test_a_path_changes_its_settings_and_refuses_the_ones_it_was_made_with(small_bundle):
    from relight import load_environment
    from relight.engine.frame_path import FramePath

    with pytest.raises(InputError, match="give a FrameSettings"):
        FramePath(small_bundle, load_environment("builtin:sunset"), {"mode": "paste"})
    with FramePath(small_bundle, load_environment("builtin:sunset"), FrameSettings(focal="ortho")) as fp:
        before = fp.settings
        fp.update(strength=0.25, exposure=-1.0)
        fp.set_mode("paste")
        assert (fp.settings.strength, fp.settings.exposure, fp.settings.mode) == (0.25, -1.0, "paste")
        with pytest.raises(InputError, match="field_rows, focal: set when the frame path is made"):
            fp.update(focal=300.0, field_rows=64)
        with pytest.raises(InputError, match="strength 3"):
            fp.set_strength(3)
        assert fp.settings.strength == 0.25 and before.strength == 1.0  # refused: unchanged
