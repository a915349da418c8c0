"""The composite kernels against their NumPy twins; the live ratio, the person's maps and pass."""

import cv2
import numpy as np
import pytest

from relight import load_environment
from relight.directions import rotation_matrix
from relight.engine.frame_settings import FrameSettings

from .tolerances import (
    COMPOSITE_TWIN_CODES,
    LIVE_RATIO_BOUND_CODES,
    PERSON_ASYNC_MEAN_CODES,
    STROKE_DARKER,
    STROKES_KEPT_SHARE,
    TRUST_HIGH_SHARE,
    TRUST_LOW_SHARE,
)


@pytest.mark.parametrize("mode", ["ambient", "paste", "live"])
def test_warp_composite_kernel_matches_its_numpy_twin(frame_path, clip, mode):
    from relight.engine.warp import GRID_STEP, coarse_map, points_box
    from relight.kernels.composite_twin import warp_composite_numpy

    _, frames = clip
    fp = frame_path
    rgb = frames[5]
    rng = np.random.default_rng(4)
    # Control points: the reference landmarks moved by a small affine map plus noise.
    ref = fp.rig.control_ref
    a = np.array([[1.03, 0.04], [-0.03, 0.98]])
    cur = (ref - ref.mean(0)) @ a.T + ref.mean(0) + np.array([4.0, -3.0]) + rng.normal(0, 0.3, ref.shape)
    h, w = rgb.shape[:2]
    box = points_box(cur, (w, h), pad=0)
    coarse = coarse_map(cur, ref, box)
    fp.relighter.relight(load_environment("builtin:studio"), rotation_matrix(8, -4, 2))
    # The live slot: the face under a light from the left (some of it dark: the trust ramps act).
    live, live_median = _live_slot(fp, [-0.8, 0.2, 0.55])
    settings = dict(mode=mode, gain=1.3, strength=0.8, eps=float(fp.rig.ratio_eps), ratio_max=6.0,
                    live_median=live_median)
    turn = rotation_matrix(25, -10, 5)  # some of the face turned away: it fades out
    lines = np.zeros((h, w), np.uint8)
    if mode == "live":  # dark strokes of another colour than the face (glasses' rims): kept
        rgb = rgb.copy()
        for k in range(3):
            y = box[1] + (k + 1) * (box[3] - box[1]) // 4
            for img, colour in ((rgb, (20, 20, 25)), (lines, 1)):
                cv2.line(img, (box[0] + 4, y), (box[2] - 4, y + 6), colour, 2)
    got = fp.compositor.run(rgb, box, coarse, GRID_STEP, relit=fp.relighter.buffer(), live=fp.relighter.slot("live")[1],
                            rotation=turn, **settings)
    layer = _layer_numpy(fp, turn, live=live, **settings)
    if mode == "live":
        s = layer[0][..., 3][fp.rig.alpha_crop > 0.5]
        # the live pixel trusted in places, and distrusted in others
        # trust spans both ends (0.05/0.95: 'near 0', 'near 1') (definitional bound, not a tolerance)
        assert (s < 0.05).mean() > TRUST_LOW_SHARE and (s > 0.95).mean() > TRUST_HIGH_SHARE
    want = warp_composite_numpy(rgb, box, coarse, GRID_STEP, fp.rig.origin, layer, mode=mode)
    diff = np.abs(got.astype(int) - want.astype(int))
    assert (np.abs(want.astype(int) - rgb.astype(int)).sum(axis=2) > 3).sum() > 1000  # it did something
    # differing pixels: a rounding-level share (1 %) (definitional bound, not a tolerance)
    assert diff.max() <= COMPOSITE_TWIN_CODES and (diff > 0).mean() < 0.01
    if mode == "live":  # the strokes stay darker than the face composited there without them, in
        # both - most of them: where the live light leaves the face black, black has no colour to
        # tell a stroke by
        on = (lines > 0) & (np.abs(want.astype(int) - rgb.astype(int)).sum(axis=2) > 3)
        plain = warp_composite_numpy(frames[5], box, coarse, GRID_STEP, fp.rig.origin, layer, mode=mode)
        ref = plain.astype(np.float32).mean(axis=2)[on]
        for out in (got, want):
            kept = out.astype(np.float32).mean(axis=2)[on] < STROKE_DARKER * ref
            assert kept.mean() > STROKES_KEPT_SHARE, kept.mean()


def test_the_live_ratio_lifts_nothing_the_target_light_darkens(frame_path):
    """Mode live, the live pixel fully trusted: where the target leaves a pixel darker than the live
    light does (T < E), the relit face follows the live pixel's own departure from E and no more -
    face <= T max(f / E, 1). A ratio regularised as (T + eps) / (E + eps) broke this: it lifted T
    by eps (1 - T / E), most where the target shades what the live light lit (a real face under a
    side light, relit toward a light from the other side: +0.006 linear in its shadows)."""
    from relight.colour import LUMINANCE, decode_srgb8, encode_srgb8
    from relight.engine.warp import GRID_STEP, coarse_map, points_box
    from relight.kernels.composite_twin import build_layer_numpy

    fp = frame_path
    main = np.array(fp.relighter.relight_texels(_texel_point(fp.relighter, [-0.8, 0.1, 0.6])))  # the target
    live, live_median = _live_slot(fp, [0.8, 0.1, 0.6])  # the live light: from the other side
    k = 1.15  # the live frame 15 % brighter than the live light predicts: a departure the ratio carries
    frame = encode_srgb8(np.clip(k * live, 0.0, 1.0))
    ref = fp.rig.control_ref
    h, w = frame.shape[:2]
    box = points_box(ref, (w, h), pad=0)
    coarse = coarse_map(ref, ref, box)  # the frame is the reference: the identity warp
    settings = dict(mode="live", gain=1.0, strength=1.0, eps=float(fp.rig.ratio_eps), ratio_max=6.0,
                    live_median=live_median)
    got = decode_srgb8(fp.compositor.run(frame, box, coarse, GRID_STEP, relit=fp.relighter.buffer(main),
                                         live=fp.relighter.slot("live")[1], **settings))
    layer, expect, _ = build_layer_numpy(main, fp.rig.fill_flat.reshape(fp.rig.alpha_crop.shape),
                                      fp.rig.inv_ambient, fp.rig.alpha_crop, fp.compositor.normal, np.eye(3),
                                      live=live, **settings)
    # crop pixels wholly composited and trusted, where the target leaves a quarter of the live light or less
    ox, oy = fp.rig.origin
    t = layer[..., 4:7]
    f_lin = decode_srgb8(frame)[oy:oy + layer.shape[0], ox:ox + layer.shape[1]]
    sel = ((layer[..., 7] > 0.999) & (layer[..., 3] > 0.999) & (t @ LUMINANCE < 0.25 * expect[..., 3])
           & (f_lin.max(axis=2) < 0.85))
    sel[:2] = sel[-2:] = False
    sel[:, :2] = sel[:, -2:] = False
    assert sel.sum() > 200, sel.sum()  # the case is there
    out = encode_srgb8(got[oy:oy + layer.shape[0], ox:ox + layer.shape[1]][sel]).astype(int)
    bound = encode_srgb8(np.clip(k * t[sel], 0.0, 1.0)).astype(int)  # f = k E: T max(f / E, 1) = k T
    excess = (out - bound).max(axis=1)
    assert np.quantile(excess, 0.99) <= LIVE_RATIO_BOUND_CODES, np.quantile(excess, [0.5, 0.99])


def test_the_persons_maps_are_not_reused_across_a_new_environment_or_a_gap(small_bundle, clip, monkeypatch):
    """The person's maps are reused between frames (the scheduler remakes them when the head moved
    or turned enough, or they aged), but never across a change of environment or a frame without
    the face: the frame after either is what a path remaking them every frame gives (the old ratio
    left the person under the last environment's change of light for a frame; a matte from before
    the gap would sit where the person was). The field is remade every frame in both runs, and the
    matte trusted on its own (not after a run of remakes, which the two runs count differently)."""
    from relight.engine import frame_path as fpm
    from relight.engine import head_light, schedule

    _, frames = clip
    env, new = load_environment("builtin:sunset"), load_environment("builtin:window")
    outs = []
    monkeypatch.setattr(schedule, "FIELD_MAX_AGE", 1)
    monkeypatch.setattr(head_light, "MATTE_TRUST_RUN", 1)
    for every in (schedule.PERSON_MAX_AGE, 1):
        monkeypatch.setattr(schedule, "PERSON_MAX_AGE", every)
        fp = fpm.FramePath(small_bundle, env, FrameSettings(region="person"))
        run = [fp.process(f, i / 30) for i, f in enumerate(frames[:7])]
        assert all(info.face for _, info in run)
        for k in (7, 8):  # two switches in a row
            fp.set_environment(new)
            run.append(fp.process(frames[k], k / 30))
            assert "person" in run[-1][1].ran  # made for the new light
            fp.set_environment(env)
        run.append(fp.process(frames[9], 9 / 30))
        gap, _ = fp.process(np.full_like(frames[0], 90), 10 / 30)  # the room without the person
        run.append(fp.process(frames[11], 11 / 30))
        assert "person" in run[-1][1].ran  # made again after the gap
        outs.append([o for o, _ in run])
    reused, remade = outs
    assert any(not np.array_equal(a, b) for a, b in zip(reused[:7], remade[:7], strict=True))  # it does reuse
    for k in (7, 8, 10):
        assert np.array_equal(reused[k], remade[k])


def test_a_live_source_makes_the_persons_maps_beside_its_frames(small_bundle, clip, monkeypatch):
    """live_source (relight live): the light field, the person's maps and the live light's fit
    made on workers while the frames go on with the newest made - frames relit as the path making
    them in the frame does but for their age (close, not the same), the workers' maps and fits
    taken into use, and a new environment never served a map made for the old one (the field
    made after the switch makes its own)."""
    import threading

    from relight.engine import frame_light, frame_person, schedule
    from relight.engine import frame_path as fpm

    _, frames = clip
    # the maps and the fits made at least every third frame (the clip's head moves little)
    monkeypatch.setattr(schedule, "PERSON_MAX_AGE", 3)
    monkeypatch.setattr(schedule, "LIGHT_MAX_AGE", 3)
    env, new = load_environment("builtin:sunset"), load_environment("builtin:window")
    taken, fitted = [], []
    real, real_fit = frame_person.PersonStage.took, frame_light.LiveLightStage.fit

    def took(self, made):
        taken.append(self.live_source())
        return real(self, made)

    def fit(self, *a):
        fitted.append(threading.current_thread().name)
        return real_fit(self, *a)

    monkeypatch.setattr(frame_person.PersonStage, "took", took)
    monkeypatch.setattr(frame_light.LiveLightStage, "fit", fit)
    outs = []
    for live in (False, True):
        fp = fpm.FramePath(small_bundle, env, FrameSettings(region="person", live_source=live, focal="ortho"))
        run = []
        for i, f in enumerate(frames[:12]):
            run.append(fp.process(f, i / 30))
            if live:  # the worker's field and maps are ready by the next frame here (a slow machine's may not)
                fp.join()
                for job in (fp.person.job, fp.live_light.job):
                    if job is not None:
                        job.result()
        assert all(info.face for _, info in run)
        fp.set_environment(new)
        before = len(taken)
        run.append(fp.process(frames[12], 12 / 30))
        fp.join()  # (a live source's field made beside the frames, for the new environment)
        assert len(taken) == before + 1 and fp.person.job is None  # the maps made for it, in it
        outs.append([o for o, _ in run])
    sync, live = outs
    assert taken.count(True) >= 3  # maps made on the worker were used (beyond the first, made in the frame)
    assert sum(name.startswith("relight-maps") for name in fitted) >= 3  # and fits
    for a, b, f in zip(sync[:12], live[:12], frames, strict=False):
        changed = (a != f).any(axis=2)
        d = np.abs(a.astype(int) - b)[changed]
        assert changed.sum() > 300 and d.mean() < PERSON_ASYNC_MEAN_CODES
    assert any(not np.array_equal(a, b) for a, b in zip(sync[2:12], live[2:12], strict=True))  # a frame older


def test_a_setting_set_again_unchanged_does_not_wait_for_the_slow_stages(small_bundle, clip):
    """The service sets every frame's settings: a setter whose value does not change leaves the
    slow stages beside a live source's frames running; one that changes waits for them (they
    read it). Paths given the same workers (a service's stream clients) share them."""
    import threading
    from concurrent.futures import Future

    from relight.engine import frame_path as fpm
    from relight.engine.threads import Worker

    _, frames = clip
    workers = (Worker("relight-field"), Worker("relight-maps"))
    settings = FrameSettings(region="face", live_source=True)
    fp = fpm.FramePath(small_bundle, load_environment("builtin:sunset"), settings, workers=workers)
    other = fpm.FramePath(small_bundle, load_environment("builtin:sunset"), settings, relighter=fp.relighter,
                          workers=workers)
    assert fp.workers[0] is other.workers[0] and fp.person.worker is other.live_light.worker is workers[1]
    fp.process(frames[0], 0.0)
    job = Future()  # a field being made beside the frames, not done yet
    fp._field_job = job
    done = threading.Event()

    def set_all_again():
        fp.set_mode(fp.settings.mode)
        fp.set_strength(fp.settings.strength)
        fp.set_exposure(0.0)
        fp.set_env_turn(fp.settings.env_turn)
        done.set()

    threading.Thread(target=set_all_again, daemon=True).start()
    assert done.wait(5.0)  # (returned at once: nothing changed)
    changed = threading.Event()
    threading.Thread(target=lambda: (fp.set_strength(0.5), changed.set()), daemon=True).start()
    assert not changed.wait(0.3)  # waits for the field in flight
    job.set_result(None)
    assert changed.wait(5.0) and fp.settings.strength == 0.5


def _person_grid(rng, shape):
    """A person grid (rho - 1, matte) with a matte edge and a place where nothing changes."""
    grid = np.zeros((*shape, 4), np.float32)
    grid[..., :3] = (rng.random((*shape, 3)) - 0.5) * 2.0
    grid[:, shape[1] // 4:, 3] = 1.0  # the person: all but the left quarter
    grid[: shape[0] // 3, shape[1] // 2:, 3] = 0.4  # a soft part
    return grid


def face_layer(fp, frames, rng):
    """A frame, the face's box and coarse map in it (the reference moved a little by ``rng``), the
    layer's head turn, and the layer built for it (mode live, a live light from the left): (frame,
    face box, coarse map, turn, the live slot's frame, the layer's settings)."""
    from relight.engine.warp import coarse_map, points_box

    rgb = frames[5]
    ref = fp.rig.control_ref
    cur = ref + np.array([3.0, -2.0]) + rng.normal(0, 0.3, ref.shape)
    h, w = rgb.shape[:2]
    face_box = points_box(cur, (w, h), pad=0)
    coarse = coarse_map(cur, ref, face_box)
    fp.relighter.relight(load_environment("builtin:studio"), rotation_matrix(5, -3, 1))
    live, live_median = _live_slot(fp, [-0.7, 0.2, 0.6])
    settings = dict(mode="live", gain=1.2, strength=1.0, eps=float(fp.rig.ratio_eps), ratio_max=6.0,
                    live_median=live_median)
    turn = rotation_matrix(10, -5, 2)
    fp.compositor.layer(relit=fp.relighter.buffer(), live=fp.relighter.slot("live")[1], rotation=turn, **settings)
    return rgb, face_box, coarse, turn, live, settings


@pytest.mark.parametrize("scale", [1.0, (2.5, 2.4)])
def test_composite_person_kernel_matches_its_numpy_twin(frame_path, clip, scale):
    """The whole person in one pass (the face's composite inside its box, the light's change
    over the person's matte beyond): the kernel and its NumPy twin give the same bytes but for
    rounding - on the frame (scale 1) and on a smaller copy of it (the work scale's pass); with
    no person grid, the face's composite alone, as warp_composite makes it."""
    from relight.engine.warp import GRID_STEP
    from relight.kernels.composite_twin import composite_person_numpy

    _, frames = clip
    fp = frame_path
    rng = np.random.default_rng(11)
    rgb, face_box, coarse, turn, live, settings = face_layer(fp, frames, rng)
    h, w = rgb.shape[:2]
    layer = _layer_numpy(fp, turn, live=live, **settings)
    sx, sy = np.broadcast_to(np.asarray(scale, float), (2,))
    img = rgb if sx == 1.0 else cv2.resize(rgb, (round(w / sx), round(h / sy)), interpolation=cv2.INTER_AREA)
    grid = _person_grid(rng, (h // 8, w // 8))
    box = (2, 1, img.shape[1] - 1, img.shape[0] - 2)
    args = (img, box, face_box, coarse, GRID_STEP)
    for person, gate in ((grid, False), (grid, True), (None, False)):
        got = fp.compositor.composite_person(*args, mode="live", scale=scale, person=person, frame_size=(w, h),
                                             floor=0.02, gate=gate)
        want = composite_person_numpy(*args[:4], GRID_STEP, fp.rig.origin, layer, mode="live", scale=scale,
                                      person=person, frame_size=(w, h), floor=0.02, gate=gate)
        diff = np.abs(got.astype(int) - want.astype(int))
        changed = np.abs(want.astype(int) - img.astype(int)).sum(axis=2) > 3
        assert changed.sum() > 300  # it did something
        assert diff.max() <= COMPOSITE_TWIN_CODES and (diff > 0).mean() < 0.01
        assert (got[:box[1]] == img[:box[1]]).all() and (got[:, box[2]:] == img[:, box[2]:]).all()
    if sx == 1.0:  # no person: the face's composite, as warp_composite makes it
        np.testing.assert_array_equal(got, fp.compositor.composite(img, face_box, coarse, GRID_STEP, mode="live"))


@pytest.mark.parametrize("scale", [1.0, (2.5, 2.4)])
def test_the_composite_skips_only_work_groups_it_would_leave_as_they_are(frame_path, clip, scale, monkeypatch):
    """The composite kernels skip the work-groups the face cannot reach and the person's matte
    does not cover (compositor.work_groups): the same bytes as with every group run - with the
    person and without, gated and not, on the frame and on a smaller copy - and they do skip."""
    from relight.engine.warp import GRID_STEP, coarse_map, points_box
    from relight.kernels import compositor as cm

    _, frames = clip
    fp = frame_path
    rgb = frames[5]
    rng = np.random.default_rng(3)
    ref = fp.rig.control_ref
    cur = ref + np.array([-4.0, 3.0]) + rng.normal(0, 0.3, ref.shape)
    h, w = rgb.shape[:2]
    face_box = points_box(cur, (w, h), pad=0)
    coarse = coarse_map(cur, ref, face_box)
    fp.relighter.relight(load_environment("builtin:studio"), rotation_matrix(-5, 3, 1))
    _, live_median = _live_slot(fp, [0.6, 0.3, 0.7])
    fp.compositor.layer(relit=fp.relighter.buffer(), live=fp.relighter.slot("live")[1],
                        rotation=rotation_matrix(8, 4, 0), mode="live", gain=1.1, strength=1.0,
                        eps=float(fp.rig.ratio_eps), ratio_max=6.0, live_median=live_median)
    sx, sy = np.broadcast_to(np.asarray(scale, float), (2,))
    img = rgb if sx == 1.0 else cv2.resize(rgb, (round(w / sx), round(h / sy)), interpolation=cv2.INTER_AREA)
    grid = _person_grid(rng, (h // 8, w // 8))
    grid[:, : grid.shape[1] // 4, 3] = 0.0  # a quarter of the frame off the person
    box = (0, 0, img.shape[1], img.shape[0])
    real = cm.work_groups
    skipped = []

    def counted(*a, **k):
        flags = real(*a, **k)
        skipped.append(float((flags == 0).mean()))
        return flags

    runs = [dict(person=grid, gate=False), dict(person=grid, gate=True), dict(person=None, gate=False)]
    for kw in runs:
        monkeypatch.setattr(cm, "work_groups", counted)
        got = fp.compositor.composite_person(img, box, face_box, coarse, GRID_STEP, mode="live", scale=scale,
                                             frame_size=(w, h), floor=0.02, **kw)
        monkeypatch.setattr(cm, "work_groups", lambda *a, **k: np.full_like(real(*a, **k), 3))
        every = fp.compositor.composite_person(img, box, face_box, coarse, GRID_STEP, mode="live", scale=scale,
                                               frame_size=(w, h), floor=0.02, **kw)
        assert (got != img).any(axis=2).sum() > 300  # it did something
        np.testing.assert_array_equal(got, every)
    if sx == 1.0:  # the face's own kernel (region face) skips as well
        monkeypatch.setattr(cm, "work_groups", counted)
        got = fp.compositor.composite(img, face_box, coarse, GRID_STEP, mode="live")
        monkeypatch.setattr(cm, "work_groups", lambda *a, **k: np.full_like(real(*a, **k), 3))
        np.testing.assert_array_equal(got, fp.compositor.composite(img, face_box, coarse, GRID_STEP, mode="live"))
    assert min(skipped) > 0.05, skipped  # every pass skipped groups


def _no_face(compositor, frame, grid, box=None):
    """composite_person with the person grid alone (a face box of no size)."""
    from relight.engine.warp import GRID_STEP

    h, w = frame.shape[:2]
    return compositor.composite_person(frame, box or (0, 0, w, h), (0, 0, 0, 0), np.zeros((3, 3, 2), np.float32),
                                       GRID_STEP, mode="live", person=grid, frame_size=(w, h), floor=0.02)


def test_the_person_pass_reads_a_box_of_the_grid_as_the_whole_grid(frame_path, clip):
    """The person's maps made over the box the person reaches (PersonMaps: a grid of that box,
    its origin in the work grid): the kernel and its twin read it as the whole grid it is cut
    from - the same bytes but for rounding - on the frame and on a box of it (offset)."""
    from relight.engine.warp import GRID_STEP
    from relight.kernels.composite_twin import composite_person_numpy

    _, frames = clip
    rgb = frames[5]
    h, w = rgb.shape[:2]
    gh, gw = h // 4, w // 4
    rng = np.random.default_rng(5)
    whole = np.zeros((gh, gw, 4), np.float32)
    whole[..., :3] = (rng.random((gh, gw, 3)) - 0.5) * 1.5
    cy0, cy1, cx0, cx1 = gh // 5, 4 * gh // 5, gw // 3, 5 * gw // 6
    whole[cy0 + 2:cy1 - 2, cx0 + 2:cx1 - 2, 3] = rng.random((cy1 - cy0 - 4, cx1 - cx0 - 4)) * 0.6 + 0.4
    part = np.ascontiguousarray(whole[cy0:cy1, cx0:cx1])
    assert (_no_face(frame_path.compositor, rgb, whole) != rgb).any(axis=2).sum() > 1000  # it did something
    for offset in ((0, 0), (40, 24)):
        img = np.ascontiguousarray(rgb[offset[1]:, offset[0]:])
        ih, iw = img.shape[:2]
        common = dict(mode="live", floor=0.02, offset=offset)
        args = (img, (0, 0, iw, ih), (0, 0, 0, 0), np.zeros((3, 3, 2), np.float32))
        want = frame_path.compositor.composite_person(*args, GRID_STEP, person=whole, frame_size=(w, h), **common)
        got = frame_path.compositor.composite_person(*args, GRID_STEP, person=part, person_origin=(cx0, cy0),
                                                     person_scale=(gw / w, gh / h), **common)
        twin = composite_person_numpy(*args, GRID_STEP, frame_path.rig.origin, (None, None, 0.0), person=part,
                                      person_origin=(cx0, cy0), person_scale=(gw / w, gh / h), **common)
        twin_whole = composite_person_numpy(*args, GRID_STEP, frame_path.rig.origin, (None, None, 0.0), person=whole,
                                            frame_size=(w, h), **common)
        for a, b in ((got, want), (twin, twin_whole), (got, twin)):
            diff = np.abs(a.astype(int) - b.astype(int))
            assert diff.max() <= 1 and (diff > 0).mean() < 1e-3


def test_the_person_maps_move_with_the_head(frame_path, clip):
    """PersonMaps.moved: maps made with the head at one place, used on a frame where the head (and
    the person with it) moved by (dx, dy), relight the moved person as maps made there would -
    the frame shifted, composited with the moved maps, is the composite shifted."""
    from relight.engine.person_maps import PersonMaps
    from relight.engine.warp import GRID_STEP

    _, frames = clip
    rgb = frames[5]
    h, w = rgb.shape[:2]
    gh, gw = h // 4, w // 4
    rng = np.random.default_rng(7)
    grid = np.zeros((gh, gw, 4), np.float32)
    grid[..., :3] = (rng.random((gh, gw, 3)) - 0.5) * 1.5
    grid[gh // 4:3 * gh // 4, gw // 3:2 * gw // 3, 3] = 1.0
    grid.flags.writeable = False
    maps = PersonMaps(grid, (0, 0), (gw / w, gh / h), (w // 3, h // 4, 2 * w // 3, 3 * h // 4), (100.0, 80.0))
    dx, dy = 13, 7  # not whole grid cells (4 px)
    moved = maps.moved((100.0 + dx, 80.0 + dy))
    # the box covers the maps' old place and the new (the kernel works over it)
    assert moved.box[0] <= maps.box[0] and moved.box[2] >= maps.box[2] + dx
    assert moved.box[1] <= maps.box[1] and moved.box[3] >= maps.box[3] + dy
    assert maps.moved(maps.anchor) is maps
    # a person reaching the frame's bottom edge keeps reaching it when the head moves up
    edge = PersonMaps(grid, (0, 0), (gw / w, gh / h), (w // 3, h // 4, 2 * w // 3, h), (100.0, 80.0))
    assert edge.moved((100.0, 75.0)).box[3] >= h
    shifted = np.ascontiguousarray(np.roll(rgb, (dy, dx), axis=(0, 1)))

    def composite(img, m):
        return frame_path.compositor.composite_person(img, (0, 0, w, h), (0, 0, 0, 0), np.zeros((3, 3, 2), np.float32),
                                                      GRID_STEP, mode="live", person=m.grid, person_origin=m.origin,
                                                      person_scale=m.scale, floor=0.02)

    want = np.roll(composite(rgb, maps), (dy, dx), axis=(0, 1))[dy + 2:-2, dx + 2:-2]
    got = composite(shifted, moved)[dy + 2:-2, dx + 2:-2]
    assert (composite(rgb, maps) != rgb).any(axis=2).sum() > 1000  # it did something
    diff = np.abs(got.astype(int) - want.astype(int))
    assert diff.max() <= 1, diff.max()
    unmoved = np.abs(composite(shifted, maps)[dy + 2:-2, dx + 2:-2].astype(int) - want.astype(int))
    assert unmoved.max() > 8  # the test can see a map left where the head was


def test_the_person_pass_changes_nothing_without_a_change_of_light_nor_anything_off_the_person(frame_path):
    """rho = 1 changes no byte; a brighter target brightens the person and leaves every pixel off
    the matte as it was (its bilinear reach aside); each pixel is f (1 + m (rho - 1)) in linear light."""
    from relight.colour import decode_srgb8, encode_srgb8

    rng = np.random.default_rng(0)
    h, w = 90, 160
    frame = rng.integers(20, 230, (h, w, 3)).astype(np.uint8)
    grid = np.zeros((45, 80, 4), np.float32)
    grid[10:40, 25:55, 3] = 1.0
    np.testing.assert_array_equal(_no_face(frame_path.compositor, frame, grid), frame)
    grid[..., :3] = 1.0  # twice as bright
    out = _no_face(frame_path.compositor, frame, grid)
    off = np.ones((h, w), bool)
    off[18:82, 48:112] = False
    np.testing.assert_array_equal(out[off], frame[off])
    y, x = 50, 80
    want = encode_srgb8(np.clip(decode_srgb8(frame[y, x]) * 2.0, 0, 1))
    assert np.abs(out[y, x].astype(int) - want.astype(int)).max() <= COMPOSITE_TWIN_CODES
    assert (out[25:70, 55:105].astype(int) >= frame[25:70, 55:105].astype(int)).all()


def test_the_person_region_leaves_the_face_composite_as_it_is(frame_path, clip):
    """Region person adds the ratio only beyond the face's alpha: where the face is composited in
    full (alpha 1) the output is the face's composite, even where the person's matte misses the
    face (a side-lit face's dark half) - scaling the composite by the matte there lost 0.3-1.5 dB
    on every real face - unless the frame path trusts the matte (gate: it has held the face
    steadily), when the face's composite is held to it too."""
    from relight.engine.warp import GRID_STEP, coarse_map

    _, frames = clip
    fp = frame_path
    rgb = frames[5]
    h, w = rgb.shape[:2]
    ref = fp.rig.control_ref
    face_box = (int(ref[:, 0].min()), int(ref[:, 1].min()), int(ref[:, 0].max()) + 1, int(ref[:, 1].max()) + 1)
    coarse = coarse_map(ref, ref, face_box)
    fp.relighter.relight(load_environment("builtin:sunset"))
    fp.compositor.layer(relit=fp.relighter.buffer(), mode="paste", gain=1.0, strength=1.0,
                        eps=float(fp.rig.ratio_eps), ratio_max=6.0)
    face = fp.compositor.composite(rgb, face_box, coarse, GRID_STEP, mode="paste")
    grid = np.zeros((h // 4, w // 4, 4), np.float32)
    grid[..., :3] = 0.5
    grid[:, : w // 8, 3] = 1.0  # the matte: the left half of the frame only (misses the face's right)
    out = fp.compositor.composite_person(rgb, (0, 0, w, h), face_box, coarse, GRID_STEP, mode="paste", person=grid,
                                         frame_size=(w, h), floor=0.02)
    layer = _layer_numpy(fp, np.eye(3), mode="paste", gain=1.0, strength=1.0, eps=float(fp.rig.ratio_eps),
                         ratio_max=6.0).layer
    shift = np.float32([[1, 0, fp.rig.origin[0]], [0, 1, fp.rig.origin[1]]])
    alpha = cv2.warpAffine(np.ascontiguousarray(layer[..., 7]), shift, (w, h))  # the composited share
    full = alpha > 0.999
    assert full.sum() > 500
    np.testing.assert_array_equal(out[full], face[full])
    right = np.zeros((h, w), bool)
    right[:, w // 2 + 4:] = True
    np.testing.assert_array_equal(out[right & (alpha == 0)], rgb[right & (alpha == 0)])  # off the person
    left = np.zeros((h, w), bool)
    left[:, : w // 2 - 4] = True
    assert (out[left & (alpha == 0)].astype(int) >= rgb[left & (alpha == 0)].astype(int)).all()
    # With a matte the frame path trusts (gate): the face's composite held to it too - off the matte
    # the frame's bytes, the face included; on it the face's composite as it was.
    cx = (face_box[0] + face_box[2]) // 2 // 4 * 4  # the matte's edge through the face's middle
    split = grid.copy()
    split[..., 3] = 0.0
    split[:, : cx // 4, 3] = 1.0
    gated = fp.compositor.composite_person(rgb, (0, 0, w, h), face_box, coarse, GRID_STEP, mode="paste",
                                           person=split, frame_size=(w, h), floor=0.02, gate=True)
    off, on = np.zeros((h, w), bool), np.zeros((h, w), bool)
    off[:, cx + 4:] = True
    on[:, : cx - 4] = True
    assert (full & off).sum() > 100 and (full & on).sum() > 100
    np.testing.assert_array_equal(gated[off], rgb[off])
    np.testing.assert_array_equal(gated[on & full], face[on & full])


def _texel_point(relighter, direction):
    """(T, 3) texel light of one flash-strength light toward ``direction``."""
    from relight.kernels.texel_lights import point_light

    lp = point_light(np.asarray(direction, float) / np.linalg.norm(direction), relighter.map_size, relighter.texels)
    return np.repeat(lp[:, None], 3, axis=1) if lp.ndim == 1 else lp


def _live_slot(fp, direction):
    """The frame path's live slot relit by one light toward ``direction``: (the (H, W, 3) frame,
    the median luminance of the live light's sample pixels in it)."""
    live = np.array(fp.relighter.relight_texels(_texel_point(fp.relighter, direction), slot="live"))
    lum = live.reshape(-1, 3)[fp.rig.live_full] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    return live, float(np.median(lum))


def _layer_numpy(fp, rotation, **settings):
    """build_layer_numpy over the frame path's rig and relit frame (settings: its keywords)."""
    from relight.kernels.composite_twin import build_layer_numpy

    return build_layer_numpy(fp.relighter.frame, fp.rig.fill_flat.reshape(fp.rig.alpha_crop.shape),
                             fp.rig.inv_ambient, fp.rig.alpha_crop, fp.compositor.normal, rotation, **settings)
