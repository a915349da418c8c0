"""The live frame's edge cases (issue 32): each through the per-frame path on the small head's
live clip, each with the same promise - bounded output, a status, and nothing changed off the
person (every changed pixel within a margin of the head)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from relight import load_environment
from relight.video_read import read_frames

from .tolerances import (
    BEARD_DARKER_SHARE,
    EDGE_CHANGED_CODES,
    EDGE_HEAD_MARGIN_PX,
    EDGE_MIN_FOUND,
    EDGE_MIN_FOUND_OCCLUDED,
    EDGE_STILL_CODES,
    OFF_PERSON_CODES,
    OFF_PERSON_MEAN_CODES,
    SHADOW_CODES_GAIN,
    SHADOW_KEPT_SHARE,
    SHADOW_SETTLE_FRAMES,
)


@pytest.fixture(scope="module")
def path(small_bundle):
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    # (the studio's frames are orthographic: told so - the focal search has its own tests)
    return FramePath(small_bundle, load_environment("builtin:sunset"), FrameSettings(focal="ortho"))


@pytest.fixture(scope="module")
def frames(live_clip):
    return list(read_frames(live_clip))


@pytest.fixture(scope="module")
def head(small_bundle):
    """Where the person may change: the reference's head mask grown by EDGE_HEAD_MARGIN_PX (the
    live clip turns the same head by up to 10 degrees in place)."""
    m = np.asarray(small_bundle.mask, np.uint8)
    k = 2 * EDGE_HEAD_MARGIN_PX + 1
    return cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0


def _run(path, frames, head=None):
    """(outputs, infos) of a fresh run; every output the input's shape and type, and (``head``)
    changed only on the head."""
    path.reset()
    outs, infos = [], []
    for i, f in enumerate(frames):
        out, info = path.process(f, i / 30)
        assert out.shape == f.shape and out.dtype == np.uint8
        assert info.face or info.note, "a frame without a face says why"
        if head is not None:
            # off the person: issue 32's goals - a stray pixel of the person's matte at most (the
            # mean change and its 99.9th percentile, 8-bit codes), never a smear
            off = np.abs(out.astype(np.int16) - f.astype(np.int16)).max(axis=2)[~head]
            assert off.mean() <= OFF_PERSON_MEAN_CODES and np.percentile(off, 99.9) <= OFF_PERSON_CODES, \
                f"frame {i}: {int((off > EDGE_CHANGED_CODES).sum())} pixels changed off the head"
        outs.append(out)
        infos.append(info)
    return outs, infos


def test_a_person_who_leaves_and_comes_back(path, frames, head):
    empty = np.full_like(frames[0], 90)  # the room without the person
    seq = frames[:10] + [empty] * 8 + frames[10:30]
    outs, infos = _run(path, seq, head)
    for k in range(10, 18):
        assert not infos[k].face and np.array_equal(outs[k], empty)
    back = [i.face for i in infos[18:]]
    assert back.index(True) <= 2 and np.mean(back) >= EDGE_MIN_FOUND


def test_two_faces_in_the_frame_the_bundles_person_is_relit(path, frames):
    """A second, different person beside the bundle's (scikit-image's astronaut photo): only the
    bundle's person changes."""
    skimage_data = pytest.importorskip("skimage.data", reason="scikit-image gives the second face")
    other = skimage_data.astronaut()[30:250, 130:350]  # her face, 220x220
    h, w = frames[0].shape[:2]
    other = cv2.resize(other, (h, h), interpolation=cv2.INTER_AREA)
    seq = [np.ascontiguousarray(np.concatenate([f, other], axis=1)) for f in frames[:20]]
    outs, infos = _run(path, seq)
    assert np.mean([i.face for i in infos]) >= EDGE_MIN_FOUND
    for out, f in zip(outs, seq, strict=True):
        assert np.array_equal(out[:, w:], f[:, w:])  # the other person untouched


@pytest.mark.parametrize("kind", ["hand", "glasses"])
def test_a_hand_over_the_face_and_glasses(path, frames, head, kind, small_bundle):
    lm = np.asarray(small_bundle.landmarks, np.float32).reshape(-1, 2)
    x0, y0 = lm.min(axis=0)
    x1, y1 = lm.max(axis=0)
    cx = (x0 + x1) / 2
    seq = []
    hand = np.zeros(frames[0].shape[:2], np.uint8)
    cv2.ellipse(hand, (int(cx), int(y1)), (int((x1 - x0) * 0.45), int((y1 - y0) * 0.25)), 0, 0, 360, 1, -1)
    for i, f in enumerate(frames[:30]):
        f = f.copy()
        if kind == "hand" and 8 <= i < 20:  # a skin-coloured hand over the mouth and chin (brighter than
            # the face: it used to change the tracking copy's brightening and lose every point at once)
            f[hand > 0] = (205, 150, 120)
        if kind == "glasses":  # dark rims over the eyes
            f = _rims(f, small_bundle)[0]
        seq.append(f)
    # the hand is the person's too: it may take the new light (region person)
    outs, infos = _run(path, seq, head | (cv2.dilate(hand, np.ones((5, 5), np.uint8)) > 0) if kind == "hand" else head)
    found = [i.face for i in infos]
    if kind == "hand":  # found at once and held through the hand
        assert all(found)
    else:  # dark rims the reference does not have: found within the search's first back-off steps
        assert found.index(True) <= 5 and np.mean(found) >= EDGE_MIN_FOUND_OCCLUDED


def test_a_hand_over_the_whole_face_then_leaving(path, frames, head, small_bundle):
    """A skin-coloured hand covers the whole face for 10 frames, then leaves (issue 49): while it
    covers it nothing but the hand and the person may change, and the face is found again within
    3 frames of being back in view."""
    lm = np.asarray(small_bundle.landmarks, np.float32).reshape(-1, 2)
    x0, y0 = lm.min(axis=0)
    x1, y1 = lm.max(axis=0)
    hand = np.zeros(frames[0].shape[:2], np.uint8)
    cv2.ellipse(hand, (int((x0 + x1) / 2), int((y0 + y1) / 2)), (int((x1 - x0) * 0.75), int((y1 - y0) * 0.75)),
                0, 0, 360, 1, -1)
    seq = []
    for i, f in enumerate(frames[:36]):
        f = f.copy()
        if 8 <= i < 18:
            f[hand > 0] = (205, 150, 120)
        seq.append(f)
    outs, infos = _run(path, seq, head | (cv2.dilate(hand, np.ones((5, 5), np.uint8)) > 0))
    assert all(i.face for i in infos[:8])
    assert not any(i.face for i in infos[9:18])  # (the first covered frame may still hold the last pose)
    back = [i.face for i in infos[18:]]
    assert back.index(True) <= 2 and np.mean(back) >= EDGE_MIN_FOUND


def _rims(frame, small_bundle):
    """The frame with dark glasses' rims drawn over the eyes, and the rims' pixels."""
    lm = np.asarray(small_bundle.landmarks, np.float32).reshape(-1, 2)
    x0, y0 = lm.min(axis=0)
    x1, y1 = lm.max(axis=0)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    out = frame.copy()
    rim = np.zeros(frame.shape[:2], np.uint8)
    for ex in (cx - (x1 - x0) * 0.22, cx + (x1 - x0) * 0.22):
        for img, colour in ((out, (20, 20, 25)), (rim, 1)):
            cv2.ellipse(img, (int(ex), int(cy - (y1 - y0) * 0.12)), (int((x1 - x0) * 0.16), int((y1 - y0) * 0.09)),
                        0, 0, 360, colour, 2)
    return out, rim > 0


def test_glasses_stay_on_the_relit_face(path, frames, small_bundle):
    """Dark rims far darker than the live light predicts for the skin there, but of another
    colour: not a shadow (compositor.FOREIGN_RAMP) - they stay on the relit face."""
    seq, rims = zip(*(_rims(f, small_bundle) for f in frames[:20]), strict=True)
    outs, infos = _run(path, list(seq))
    ring = cv2.dilate(rims[0].astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    found = [i.face for i in infos]
    # the face behind the glasses is found (a tracker that never finds it must not pass) ...
    assert found.index(True) <= 5 and np.mean(found) >= EDGE_MIN_FOUND_OCCLUDED
    for out, info, rim in zip(outs, infos, rims, strict=True):
        if info.face:  # ... and where it is relit, the rims stay darker than around them
            lum = out.astype(np.float32).mean(axis=2)
            assert lum[rim].mean() < 0.5 * lum[ring & ~rim].mean()


def test_a_broad_shadow_is_still_taken_away(path, frames, small_bundle):
    """Mode transfer's rule that takes the glasses' rims (above): a shadow the room casts over a
    cheek, far darker than the live light predicts, is replaced by the bundle's prediction - the
    output there is what it is without the shadow, not the shadow's darkness."""
    lm = np.asarray(small_bundle.landmarks, np.float32).reshape(-1, 2)
    x0, y0 = lm.min(axis=0)
    x1, y1 = lm.max(axis=0)
    patch = np.zeros(frames[0].shape[:2], bool)
    patch[int(y0 + 0.45 * (y1 - y0)):int(y0 + 0.85 * (y1 - y0)), int(x0):int(x0 + 0.35 * (x1 - x0))] = True
    core = cv2.erode(patch.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    seq = [f.copy() for f in frames[:20]]
    for f in seq:
        f[patch] = (f[patch].astype(np.float32) * SHADOW_CODES_GAIN).astype(np.uint8)
    plain, _ = _run(path, frames[:20])
    shaded, infos = _run(path, seq)
    gaps = [np.abs(a.astype(np.float32) - b.astype(np.float32)).mean(axis=2)[core].mean()
            for a, b, i in zip(plain, shaded, infos, strict=True) if i.face]
    drop = np.abs(frames[0].astype(np.float32) - seq[0].astype(np.float32)).mean(axis=2)[core].mean()
    assert len(gaps) == 20 and drop > 30
    # once the live light has been fitted to the shadowed frames (its first fits settle over the
    # first ten frames, where the shadow fades out of the output: 19 -> 4-11 codes here)
    assert np.median(gaps[SHADOW_SETTLE_FRAMES:]) < SHADOW_KEPT_SHARE * drop, (gaps, drop)


@pytest.mark.parametrize("gain", [0.15, 2.5])
def test_a_frame_much_darker_or_brighter_than_the_capture(path, frames, head, gain):
    seq = [np.clip(f.astype(np.float32) * gain, 0, 255).astype(np.uint8) for f in frames[:20]]
    outs, infos = _run(path, seq, head)
    assert np.mean([i.face for i in infos]) >= EDGE_MIN_FOUND
    statuses = {i.light.status for i in infos if i.light is not None}
    assert statuses and statuses <= {"ok", "dark", "clipped", "few pixels"}


def test_a_camera_that_changes_exposure_mid_stream(path, frames, head):
    seq = [f if i < 15 else (f // 2) for i, f in enumerate(frames[:35])]
    outs, infos = _run(path, seq, head)
    assert all(i.face for i in infos[15:])  # the track holds through the step


@pytest.mark.parametrize("size", [(3840, 2160), (1920, 1080), (320, 180)])
def test_4k_1080p_and_320x180(path, frames, head, size):
    seq = [cv2.resize(f, size, interpolation=cv2.INTER_LINEAR) if (f.shape[1], f.shape[0]) != size else f
           for f in frames[:8]]
    big = cv2.resize(head.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    outs, infos = _run(path, seq, big)
    assert np.mean([i.face for i in infos]) >= EDGE_MIN_FOUND


def test_a_still_head_is_not_relit_again(path, frames, head):
    from relight.engine.gains import EXPOSURE_LOCK_FITS
    from relight.engine.schedule import LIGHT_SETTLE_EVERY

    settle = EXPOSURE_LOCK_FITS * LIGHT_SETTLE_EVERY + 2  # the exposure lock's first fits come while it settles
    seq = [frames[5]] * (settle + 12)
    outs, infos = _run(path, seq, head)
    assert all(i.face for i in infos)
    # once the pose filter has settled (the first re-anchoring moves the points once), the head
    # does not turn: the relight is kept, and the output holds still
    assert all(i.reused for i in infos[8:])
    assert max(np.abs(a.astype(int) - outs[-1]).max() for a in outs[-4:]) <= EDGE_STILL_CODES
    # and every slow stage idles (issue 48): the frames are tracked and the field applied, no more
    idle = [i.ran for i in infos[settle:]]
    assert not any(idle), idle


def test_a_sudden_light_change_refits_the_light_within_3_frames(path, frames, head):
    # a lamp switched on beside the camera at frame 20: the frame 1.6 times brighter from then on
    seq = frames[:20] + [np.clip(f.astype(np.float32) * 1.6, 0, 255).astype(np.uint8) for f in frames[20:30]]
    outs, infos = _run(path, seq, head)
    assert all(i.face for i in infos[20:23])
    # (refitted because the face's brightness moved - not by the settling fits' own rate)
    assert any("brightness" in i.ran.get("light", "") for i in infos[20:23]), [i.ran for i in infos[18:24]]


def test_a_live_source_refits_a_sudden_light_change_beside_its_frames(small_bundle, frames):
    """A live source makes its fields on a worker: the lamp switched on at frame 20 still starts
    a refit within 3 frames, the field made beside the frames is taken (made after the change, in
    use by frame 24), and every frame is relit meanwhile (the field in use carried)."""
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    live = FramePath(small_bundle, load_environment("builtin:sunset"), FrameSettings(live_source=True))
    seq = frames[:20] + [np.clip(f.astype(np.float32) * 1.6, 0, 255).astype(np.uint8) for f in frames[20:30]]
    infos, made = [], []
    for i, f in enumerate(seq):
        out, info = live.process(f, i / 30)
        infos.append(info)
        made.append(live.field.last.made if live.field.last is not None else -1)
        assert info.face and (out != f).any(), i  # relit on every frame, a field made or carried
        live.join()  # (frames 33 ms apart: the worker's field is ready by the next one here)
    # fields made beside the frames: a frame that started one went on with the last (carried),
    # and the next took it
    beside = [i for i, inf in enumerate(infos[1:20], 1) if "field" in inf.ran and made[i] < i]
    assert beside and all(made[i + 1] > made[i] for i in beside), (beside, made[:20])
    assert any("brightness" in i.ran.get("light", "") for i in infos[20:23]), [i.ran for i in infos[18:24]]
    assert made[24] >= 21, made[18:26]  # (frame i is the path's frame i + 1)


def test_a_very_fast_turn(path, frames, head):
    seq = frames[::6] + frames[::-6]  # every 6th frame, there and back: six times the clip's speed
    outs, infos = _run(path, seq, head)
    assert np.mean([i.face for i in infos]) >= EDGE_MIN_FOUND


def test_a_beard_the_capture_did_not_have(path, frames, head, small_bundle):
    """A dark, textured beard over the jaw and chin (issue 49): the face is still found, and the
    beard stays on the relit face - darker than the skin above it, as it came - instead of being
    filled with the bundle's skin as if it were a shadow."""
    lm = np.asarray(small_bundle.landmarks, np.float32).reshape(-1, 2)
    x0, y0 = lm.min(axis=0)
    x1, y1 = lm.max(axis=0)
    beard = np.zeros(frames[0].shape[:2], np.uint8)
    cv2.ellipse(beard, (int((x0 + x1) / 2), int(y1)), (int((x1 - x0) * 0.42), int((y1 - y0) * 0.3)), 0, 0, 180, 1, -1)
    texture = np.random.default_rng(4).integers(25, 60, size=frames[0].shape[:2])
    seq = []
    for f in frames[:20]:
        f = f.copy()
        for c, k in enumerate((1.0, 0.8, 0.65)):  # a dark brown
            f[..., c][beard > 0] = (texture[beard > 0] * k).astype(np.uint8)
        seq.append(f)
    outs, infos = _run(path, seq, head)
    assert np.mean([i.face for i in infos]) >= EDGE_MIN_FOUND
    cheek = np.zeros_like(beard)
    cv2.rectangle(cheek, (int(x0 + 0.2 * (x1 - x0)), int(y0 + 0.45 * (y1 - y0))),
                  (int(x0 + 0.8 * (x1 - x0)), int(y0 + 0.6 * (y1 - y0))), 1, -1)
    cheek &= (beard == 0) & head

    def ratio(img):  # the beard's luminance against the cheeks above it
        lum = img.astype(np.float32).mean(axis=2)
        return lum[beard > 0].mean() / lum[cheek > 0].mean()

    # (measured: 0.43-0.51 in the input, 0.64-0.77 relit under sunset; taken for a shadow and
    # filled with the bundle's skin it would be ~1)
    for out, info in zip(outs, infos, strict=True):
        if info.face:
            assert ratio(out) < BEARD_DARKER_SHARE


@pytest.mark.parametrize("cut", [0.35, pytest.param(0.7, marks=pytest.mark.slow(reason="two thirds cut (~5 s): "
                                                                                    "make test-slow"))])
def test_a_face_cut_by_the_frames_edge(path, frames, head, small_bundle, cut):
    """The head moved left until the frame's edge cuts ``cut`` of its face away (issue 49): every
    frame is relit or passed through with a status, nothing changes off the (moved) person, and
    a face a third cut is still relit."""
    lm = np.asarray(small_bundle.landmarks, np.float32).reshape(-1, 2)
    x0, x1 = lm[:, 0].min(), lm[:, 0].max()
    dx = int(round(x0 + cut * (x1 - x0)))
    w = frames[0].shape[1]

    def moved(img):  # the picture dx to the left, the right edge's column carried on
        return np.ascontiguousarray(np.concatenate([img[:, dx:], np.repeat(img[:, -1:], dx, axis=1)], axis=1))

    seq = [moved(f) for f in frames[:20]]
    head_moved = moved(head.astype(np.uint8)) > 0
    outs, infos = _run(path, seq, head_moved)
    assert all(i.face or i.note for i in infos)
    if cut < 0.5:
        assert np.mean([i.face for i in infos]) >= EDGE_MIN_FOUND_OCCLUDED
    assert all(o.shape[1] == w for o in outs)
