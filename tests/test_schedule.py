"""The per-frame path's scheduler (:mod:`relight.engine.schedule`): each rule of its table, on
heads made by hand - what runs, and that nothing runs when nothing changed."""

from __future__ import annotations

import numpy as np

from relight.directions import rotation_matrix
from relight.engine import schedule
from relight.engine.schedule import Head, Scheduler


def _head(yaw: float = 0.0, x: float = 320.0, brightness: float = 120.0, size: float = 200.0) -> Head:
    return Head((x, 180.0), rotation_matrix(yaw, 0.0, 0.0), size, brightness)


def _step(s: Scheduler, head: Head, **kw) -> schedule.Plan:
    """One frame: the plan, its stages marked as run, the next frame."""
    args = dict(relight_key_changed=False, light_wanted=True, has_light=True, person_wanted=True, has_person=True,
                new_environment=False, settings_changed=False, light_fits=1 << 30)
    args.update(kw)
    plan = s.plan(head, **args)
    for stage in plan.ran():
        s.ran(stage, head)
    s.next_frame()
    return plan


def _settled() -> Scheduler:
    """A scheduler whose every stage ran on a still head at yaw 0."""
    s = Scheduler()
    first = _step(s, _head(), relight_key_changed=True, has_light=False, has_person=False)
    assert set(first.ran()) == {"relight", "light", "person", "field"}
    return s


def test_a_still_head_runs_no_slow_stage():
    s = _settled()
    plans = [_step(s, _head()) for _ in range(schedule.LIGHT_MAX_AGE - 2)]
    assert not any(p.ran() for p in plans)


def test_a_slow_turn_carries_the_field_between_remakes_and_relights_only_with_it():
    s = _settled()
    step = 1.2 * schedule.FIELD_DEG  # every frame turns past FIELD_DEG, far below FIELD_JUMP_DEG
    assert step * schedule.FIELD_EVERY < schedule.FIELD_JUMP_DEG
    plans = [_step(s, _head(yaw=step * (i + 1))) for i in range(12)]
    made = [i for i, p in enumerate(plans) if p.field is not None]
    assert len(made) >= 12 // schedule.FIELD_EVERY - 1
    assert all(b - a == schedule.FIELD_EVERY for a, b in zip(made, made[1:], strict=False)), made
    # the relight feeds the field alone
    assert all((p.relight is None) or (p.field is not None) for p in plans)


def test_a_fast_turn_remakes_the_field_at_once():
    s = _settled()
    _step(s, _head(yaw=0.1))
    plan = _step(s, _head(yaw=0.1 + schedule.FIELD_JUMP_DEG + 0.5))
    assert plan.field is not None and plan.relight is not None


def test_a_new_light_relights_and_remakes_the_field():
    s = _settled()
    plan = _step(s, _head(), relight_key_changed=True, new_environment=True)
    assert plan.relight == "new light" and plan.field is not None and plan.person == "new light"


def test_the_room_getting_brighter_refits_the_light_on_that_frame():
    s = _settled()
    _step(s, _head())
    plan = _step(s, _head(brightness=120.0 * (1 + 2 * schedule.LIGHT_STEP)))
    assert plan.light is not None and plan.light.startswith("brightness") and plan.field is not None


def test_a_head_moving_sideways_carries_the_field_and_remakes_the_person_maps_when_it_is_far():
    s = _settled()
    size = 200.0
    small = 0.5 * schedule.PERSON_MOVE * size
    plan = _step(s, _head(x=320.0 + small, size=size))
    assert plan.person is None and plan.field is None  # carried
    plan = _step(s, _head(x=320.0 + 2.5 * schedule.PERSON_MOVE * size, size=size))
    assert plan.person is not None and plan.field is not None


def test_the_scene_test_sees_a_change_in_the_box_and_not_outside_it():
    thumb = np.full((36, 64), 100, np.uint8)
    s = Scheduler()
    base = Head((32.0, 18.0), np.eye(3), 20.0, 120.0, thumb, 1.0)
    _step(s, base, relight_key_changed=True, has_light=False, has_person=False)
    moved = thumb.copy()
    moved[:, 50:] = 200  # a hand beside the person's box
    kw = dict(person_box=(10, 5, 40, 30), field_box=(10, 5, 40, 30))
    assert not _step(s, Head(base.anchor, base.rotation, base.size, base.brightness, moved, 1.0), **kw).ran()
    moved[10:20, 20:30] = 200  # and into it
    plan = _step(s, Head(base.anchor, base.rotation, base.size, base.brightness, moved, 1.0), **kw)
    assert plan.person is not None and plan.person.startswith("scene") and plan.field is not None
