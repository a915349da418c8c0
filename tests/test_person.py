"""The person beyond the face: the shipped segmentation model finds the person the studio
rendered (against the truth's silhouette), and the light's change carried over the rest of the
person (relight.engine.head_light) keeps the frame where it must and follows the conventions."""

from __future__ import annotations

import hashlib

import cv2
import numpy as np
import pytest

from relight.engine import head_light
from relight.engine.person import PersonMatte
from relight.errors import InputError

from .tolerances import SMOOTH_BLUR_SHARE

#: The matte against the studio's silhouette (intersection over union), on a clip's frames (measured
#: 0.946 on the 320x180 cartoon head here, 0.97 at 640x360 and 0.987 on the scanned head).
MATTE_IOU = 0.92
#: Share of a frame without a person that the matte may call the person.
EMPTY_SHARE = 0.01
#: Inflated normals: the centre faces the camera, the outline faces sideways (cosines).
CENTRE_Z = 0.95
EDGE_OUTWARD = 0.7
#: The bundle's normals joined to the inflated body's: the largest step between neighbouring
#: pixels as a share of the two surfaces' difference (a fade over NORMAL_REACH x 40 px: 1/10 each).
JOIN_STEP_SHARE = 0.2
#: The person's share (head_light.person_share) on the outer 2 px of the true silhouette, at least
#: (the matte itself gives 0.72-0.77 there: the person's change faded out at its outline), and on a
#: ring 2-4 px outside it, at most (the matte gives 0.22-0.29 at this small size).
RIM_SHARE = 0.9
RING_SHARE = 0.45
#: The guided matte over a box of the frame against the whole frame's there: the filter's box
#: sums taken over another extent round differently (measured 6e-4 at most).
MATTE_BOX_ATOL = 2e-3


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A 5-frame live clip's frames (as encoded) and the person's silhouettes: the scene's own
    coverage over one half, as its truth writes them (``truth/silhouette``; without a truth
    environment rendered, which cost 10 s more)."""
    from relight.pipeline.synth.live_clip import LiveConfig, LiveScene, synthesize_live
    from relight.video_read import read_frames

    out = tmp_path_factory.mktemp("person")
    cfg = LiveConfig(width=320, height=180, duration=1.0, fps=5, seed=9)
    synthesize_live(out, cfg, progress=False)
    frames = list(read_frames(out / "live.mp4"))
    scene = LiveScene(cfg)
    sils = [scene.render(*scene.pose(i))[1] > 0.5 for i in range(len(frames))]
    return frames, sils


@pytest.mark.parametrize("module", ["relight.engine.person", "relight.engine.face_detect"])
def test_the_shipped_models_are_the_published_files_with_their_licences(module):
    """The person's segmentation model and the face detector (engine/models/, see NOTICE)."""
    import importlib

    mod = importlib.import_module(module)
    info = mod.model_info()
    data = (mod.MODEL_DIR / info["file"]).read_bytes()
    assert hashlib.sha256(data).hexdigest() == info["sha256"]
    assert "Apache License" in (mod.MODEL_DIR / info["licence"]).read_text()
    assert "Apache" in info["credit"] and "mediapipe" in info["source"]


def test_the_matte_finds_the_person_and_nothing_else(clip):
    frames, sils = clip
    pm = PersonMatte()
    for rgb, sil in zip(frames, sils, strict=True):
        m = pm(rgb)
        assert m.shape == sil.shape and m.dtype == np.float32 and 0.0 <= m.min() and m.max() <= 1.0
        p = m > 0.5
        assert (p & sil).sum() / (p | sil).sum() > MATTE_IOU
        # the same frame as a 4:3 crop (letterboxed for the model) finds the same person
        x0 = (rgb.shape[1] - rgb.shape[0] * 4 // 3) // 2
        crop = np.ascontiguousarray(rgb[:, x0:x0 + rgb.shape[0] * 4 // 3])
        q, s = pm(crop) > 0.5, sil[:, x0:x0 + rgb.shape[0] * 4 // 3]
        assert (q & s).sum() / (q | s).sum() > MATTE_IOU
    wall = np.ascontiguousarray(np.broadcast_to(np.median(frames[0], axis=(0, 1)).astype(np.uint8), frames[0].shape))
    assert (pm(wall) > 0.5).mean() < EMPTY_SHARE
    with pytest.raises(InputError, match="uint8"):
        pm(frames[0].astype(np.float32))


def test_the_person_is_relit_to_its_outline(clip):
    """The share of the person's change (head_light.person_share of the matte) is whole up to the
    true outline, and little beyond it: the matte's own ramp (the model's footprint) is not the
    person's edge."""
    frames, sils = clip
    pm = PersonMatte()
    rims, rings, raw = [], [], []
    for rgb, sil in zip(frames, sils, strict=True):
        m = pm(rgb)
        inside = cv2.distanceTransform(sil.astype(np.uint8), cv2.DIST_L2, 3)
        outside = cv2.distanceTransform((~sil).astype(np.uint8), cv2.DIST_L2, 3)
        rim, ring = sil & (inside <= 2), ~sil & (outside > 2) & (outside <= 4)
        share = head_light.person_share(m)
        assert share.dtype == np.float32 and share.min() >= 0.0 and share.max() <= 1.0
        rims.append(share[rim].mean())
        rings.append(share[ring].mean())
        raw.append(m[rim].mean())
    assert min(rims) >= RIM_SHARE, rims
    assert max(rings) <= RING_SHARE, rings
    assert max(raw) < RIM_SHARE  # the matte alone fades out at the outline: the case is there
    np.testing.assert_array_equal(head_light.person_share(np.float32([0.0, 0.1, 0.6, 1.0])), [0.0, 0.0, 1.0, 1.0])
    # the compositor's gate holds the face to the solid matte (0.5) in the share's units
    from relight.kernels.compositor import GATE_HI

    assert head_light.person_share(np.float32([0.5]))[0] == pytest.approx(GATE_HI)


def test_inflated_normals_face_the_camera_inside_and_turn_out_at_the_outline():
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w]
    disc = (((xx - 80) ** 2 + (yy - 60) ** 2) < 50 ** 2).astype(np.float32)
    n = head_light.inflate_normals(disc, 30.0)
    assert np.allclose(np.linalg.norm(n, axis=2), 1.0, atol=1e-5)
    assert n[60, 80, 2] > CENTRE_Z
    # just inside the outline: right edge toward +X, top edge toward +Y (camera up), bottom -Y
    assert n[60, 128, 0] > EDGE_OUTWARD and n[12, 80, 1] > EDGE_OUTWARD and n[108, 80, 1] < -EDGE_OUTWARD


def test_the_bundles_normals_join_the_inflated_body_without_a_step():
    """Where the bundle's cover ends (its face region on the neck, or the face's box cutting it),
    its normals are kept inside and fade into the inflated body's beyond: no pixel-to-pixel step
    anywhere (switched at the edge, the step was the two surfaces' whole difference - a block the
    ratio showed on the neck)."""
    h, w, face_px = 80, 120, 40.0
    inflated = np.zeros((h, w, 3), np.float32)
    inflated[..., 2] = 1.0
    tilt = np.array([0.6, 0.0, 0.8], np.float32)  # 37 degrees from the inflated body's
    face = np.broadcast_to(tilt, (h, w, 3)).astype(np.float32)
    cover = np.zeros((h, w), np.float32)
    cover[:, :50] = 1.0  # a hard edge, as the face's box cuts it
    n = head_light.joined_normals(inflated, face, cover, face_px)
    assert np.allclose(np.linalg.norm(n, axis=2), 1.0, atol=1e-5)
    np.testing.assert_allclose(n[:, :49], face[:, :49], atol=1e-5)  # the bundle's own, inside
    np.testing.assert_allclose(n[:, 50 + int(head_light.NORMAL_REACH * face_px) + 1:], inflated[:, 60:61].repeat(
        w - 50 - int(head_light.NORMAL_REACH * face_px) - 1, axis=1), atol=1e-5)  # the body's, beyond the reach
    step = np.degrees(np.arccos(np.clip((n[:, 1:] * n[:, :-1]).sum(axis=2), -1, 1)))
    whole = np.degrees(np.arccos(float(tilt[2])))
    assert step.max() < JOIN_STEP_SHARE * whole, (step.max(), whole)


def test_no_change_of_light_gives_a_ratio_of_one():
    """The ratio over the person is 1 where the target is the live light and the face's composite
    is its input (the person pass then changes no byte: tests/test_filter.py)."""
    from relight.colour import decode_lut8

    rng = np.random.default_rng(0)
    h, w = 90, 160
    frame = rng.integers(20, 230, (h, w, 3)).astype(np.uint8)
    matte = np.zeros((h, w), np.float32)
    matte[20:80, 50:110] = 1.0
    alpha = np.zeros((h, w), np.float32)
    alpha[35:60, 65:95] = 1.0
    sh = np.zeros((9, 3))
    sh[0] = 1.0
    sh[2] = 0.8  # a light from the front
    lin = decode_lut8()[frame]
    rho = head_light.ratio_field(lin, lin, alpha, matte, sh, sh, 25.0)
    assert np.allclose(rho, 1.0, atol=1e-4)
    brighter = head_light.ratio_field(lin, np.clip(lin * 2, 0, 1), alpha, matte, 2 * sh, sh, 25.0)
    assert (brighter[matte > 0.5] > 1.3).all()



def test_the_matte_over_the_persons_box_is_the_whole_frames(clip):
    """The person's maps are made over the box the person reaches (head_light.person_crop): the
    guided matte there is the whole frame's (but within the filter's reach of the box's edge),
    the whole frame's matte has nothing beyond the box, and the box is the person's, not the
    frame's."""
    from relight.engine.person import GUIDE_RADIUS

    frames, sils = clip
    pm = PersonMatte()
    for rgb, sil in zip(frames, sils, strict=True):
        prob = pm.probability(rgb)
        h, w = rgb.shape[:2]
        face = (w // 2 - 10, h // 3, w // 2 + 10, h // 2)
        x0, y0, x1, y1 = box = head_light.person_crop(prob, face, (w, h), 2 * GUIDE_RADIUS + 2)
        assert x0 % 2 == 0 and y0 % 2 == 0 and x0 <= face[0] and y0 <= face[1] and x1 >= face[2] and y1 >= face[3]
        assert (x1 - x0) * (y1 - y0) < 0.8 * w * h  # the person, not the frame
        whole = pm.refine(rgb, prob)
        part = pm.refine(rgb, prob, box)
        assert part.shape == (y1 - y0, x1 - x0)
        r = 2 * GUIDE_RADIUS + 1  # the guided filter's two box passes reach 2 radii
        inner = np.s_[r if y0 else 0:(y1 - y0) - (r if y1 < h else 0), r if x0 else 0:(x1 - x0) - (r if x1 < w else 0)]
        np.testing.assert_allclose(part[inner], whole[y0:y1, x0:x1][inner], atol=MATTE_BOX_ATOL)
        beyond = np.ones((h, w), bool)
        beyond[y0:y1, x0:x1] = False
        assert whole[beyond].max(initial=0.0) < 0.5  # the solid matte, all in the box
        assert sil[beyond].sum() == 0


def test_the_matte_is_trusted_only_where_it_holds_the_face():
    """The face's composite is held to the matte (gate) only where the matte covers the face's
    core: a matte that misses part of it (a side-lit face's dark half) or finds no face is not."""
    alpha = np.zeros((60, 80), np.float32)
    alpha[20:40, 30:50] = 1.0
    matte = np.zeros_like(alpha)
    matte[10:60, 20:60] = 1.0
    assert head_light.matte_trusted(matte, alpha)
    matte[20:40, 30:33] = 0.0  # 15 % of the core missed
    assert not head_light.matte_trusted(matte, alpha)
    assert not head_light.matte_trusted(matte, np.zeros_like(alpha))


def test_gaussian_smooth_follows_a_direct_gaussian():
    """The wide blurs of the person's maps, taken on halved grids: within a few percent of the
    peak of a direct Gaussian blur, and the same shape as the input."""
    from relight.engine.head_light import gaussian_smooth

    img = np.zeros((270, 480), np.float32)
    img[100:180, 200:260] = 1.0
    img[20:40, 30:400] = 0.5
    for sigma in (2.0, 8.0, 20.0, 54.0):
        want = cv2.GaussianBlur(img, (0, 0), sigma)
        got = gaussian_smooth(img, sigma)
        assert got.shape == img.shape
        assert np.abs(got - want).max() <= SMOOTH_BLUR_SHARE * want.max()
    three = np.dstack([img, 2 * img, 3 * img])
    assert gaussian_smooth(three, 20.0).shape == three.shape


def test_the_colour_check_takes_the_wall_and_keeps_grazing_skin_beside_it():
    """A plain wall (noise of ~1 Delta E) behind a person whose matte also covers a patch of the
    wall (a shoulder the model imagined): the patch goes (it looks like the wall around it), and
    skin lit at a grazing angle - a few Delta E from the wall, deep inside the matte - stays (it
    does not look like that wall: outside its own spread). The blurred rim where the matte passes
    the outline goes too (within a couple of pixels of the matte's edge the looser test is not used)."""
    rng = np.random.default_rng(7)
    h, w = 160, 200
    wall = np.array([118.0, 118.0, 120.0])
    img = wall + rng.normal(0.0, 0.7, (h, w, 3))
    yy, xx = np.mgrid[0:h, 0:w]
    head = ((xx - 100) / 45.0) ** 2 + ((yy - 80) / 55.0) ** 2 < 1.0
    img[head] = (150.0, 110.0, 90.0)
    grazing = head & (xx < 72)  # the back of the skull: darker, near the wall's grey
    img[grazing] = (124.0, 116.0, 112.0)
    rgb = np.clip(img, 0, 255).astype(np.uint8)
    rgb = cv2.GaussianBlur(rgb, (0, 0), 0.8)  # the camera's blur tints the wall at the outline
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
    lab[..., 0] *= 100.0 / 255.0
    de = np.linalg.norm(lab[grazing & (xx > 60) & (xx < 68)].mean(0) - lab[~head & (xx > 160)].mean(0))
    assert 3.0 < de < head_light.BACKGROUND_DELTA_E  # the case is there: within the old threshold
    matte = cv2.GaussianBlur(cv2.dilate(head.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(np.float32),
                             (0, 0), 1.5)
    patch = (yy > 125) & (xx > 150) & (xx < 190)  # a shoulder on the wall
    matte[patch] = 1.0
    face = np.zeros((h, w), np.float32)
    face[(np.abs(xx - 110) < 25) & (np.abs(yy - 80) < 30)] = 1.0
    out = head_light.colour_check(rgb, matte, face, 60.0)
    assert out[patch & (yy > 130) & (xx > 155) & (xx < 185)].max() < 0.1  # the imagined shoulder is the wall
    inner = cv2.erode(head.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0  # (4 px inside the outline)
    assert out[grazing & inner].min() > 0.9  # grazing skin stays the person
    rim = (cv2.dilate(head.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0) & ~head & (yy < 120)
    assert out[rim].mean() < 0.5 * matte[rim].mean()  # the rim past the outline mostly goes
