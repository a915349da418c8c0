"""The light field (issue 48): its kernels against their NumPy twins, the field made at the
frame's own scale giving the composite back, a unit field giving the frame back, the field carried
with the head, and the frame's planes read and scaled as its RGB is."""

import cv2
import numpy as np
import pytest

from relight.directions import rotation_matrix

from .tolerances import COMPOSITE_TWIN_CODES, FIELD_CODES_REL, FIELD_SAMPLE_CODES, FIELD_TWIN_CODES, FIELD_TWIN_REL


def _grid(rng, shape):
    """A field (gh, gw, 32): two maps of codes near the identity (gains 0.5-2, a little of the
    other channels, offsets of tens of codes), a cover with holes (cells that change nothing)."""
    g = np.zeros((*shape, 32), np.float32)
    for at in (0, 12):
        m = np.broadcast_to(np.hstack([np.eye(3), np.zeros((3, 1))]), (*shape, 3, 4)).copy()
        m[..., :, :3] *= rng.uniform(0.5, 2.0, (*shape, 3, 1))
        m[..., :, :3] += rng.uniform(-0.05, 0.05, (*shape, 3, 3))
        m[..., :, 3] = rng.uniform(-30, 30, (*shape, 3))
        g[..., at:at + 12] = m.reshape(*shape, 12)
    g[..., 24] = rng.uniform(0, 1, shape) > 0.3
    g[0, :, 24] = 0.0
    g[..., 25:28] = rng.uniform(40, 200, (*shape, 3))  # the cells' colour: pixels either side of it
    return g


def _planes(rgb):
    from relight.video_yuv import rgb_to_planes

    return rgb_to_planes(rgb)


@pytest.mark.parametrize("factor, corner", [(4, (2, -6)), (6, (8, 4)), (2, (0, 0)), (12, (4, -12)), (16, (-16, 8))])
@pytest.mark.parametrize("sub", [2, 1])
def test_the_field_kernels_match_their_numpy_twins(sub, factor, corner):
    """field_rgb and field_planes (4:2:0 and 4:2:2) give their twins' bytes, with gains, offsets
    and cells of no change, at fields of several factors and corners (the tiles' weights); they
    change pixels only inside the box."""
    from relight.kernels.field_apply import FieldApplier
    from relight.kernels.field_twin import field_planes_numpy, field_rgb_numpy

    rng = np.random.default_rng(7)
    h, w = 72, 128
    rgb = cv2.GaussianBlur(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), (0, 0), 1.5)
    grid = _grid(rng, (h // factor + 2, w // factor + 2))
    box = (5, 3, 121, 70)
    fa = FieldApplier()
    got = fa.rgb(rgb, box, grid, factor, corner)
    want = field_rgb_numpy(rgb, box, grid, factor, corner)
    assert np.abs(got.astype(int) - want).max() <= FIELD_TWIN_CODES
    assert (got != rgb).any(axis=2).mean() > 0.3  # it did something
    assert (got[:box[1]] == rgb[:box[1]]).all() and (got[:, box[2]:] == rgb[:, box[2]:]).all()
    y, u, v = _planes(rgb)
    if sub == 1:  # 4:2:2: the chroma of every row
        u, v = (np.ascontiguousarray(cv2.resize(p, (w // 2, h), interpolation=cv2.INTER_LINEAR)) for p in (u, v))
    got = fa.planes(y, u, v, box, grid, factor, corner)
    want = field_planes_numpy(y, u, v, box, grid, factor, corner)
    for a, b, before in zip(got, want, (y, u, v), strict=True):
        assert np.abs(a.astype(int) - b).max() <= FIELD_TWIN_CODES
        assert (a != before).mean() > 0.3


def test_a_field_of_no_change_gives_the_frame_back():
    """The code maps of a change of nothing (G 1, B 0: code_grid) over every cell, covering it: an
    RGB frame and a frame's planes come back bit for bit."""
    from relight.engine.field import code_grid
    from relight.kernels.field_apply import FieldApplier
    from relight.video_yuv import YuvFrame

    rng = np.random.default_rng(2)
    rgb = cv2.GaussianBlur(rng.integers(0, 256, (64, 96, 3), dtype=np.uint8), (0, 0), 2.0)
    cells = np.zeros((9, 13, 8), np.float32)
    cells[..., :4] = 1.0
    colour = rng.integers(0, 256, (9, 13, 3), dtype=np.uint8)
    fa = FieldApplier()
    np.testing.assert_array_equal(fa.rgb(rgb, (0, 0, 96, 64), code_grid(cells, colour), 8, (0, 0)), rgb)
    frame = YuvFrame(*_planes(rgb))
    planes = (frame.y, frame.u, frame.v)
    unit = code_grid(cells, colour, *frame.code_maps())
    for a, b in zip(fa.planes(*planes, (0, 0, 96, 64), unit, 8, (0, 0)), planes, strict=True):
        np.testing.assert_array_equal(a, b)


def _face_setup(fp, frames, rng):
    """(frame, face box, coarse map, grid step, the layer's settings): :func:`.test_composite.face_layer`."""
    from relight.engine.warp import GRID_STEP

    from .test_composite import face_layer

    rgb, face_box, coarse, _, live, settings = face_layer(fp, frames, rng)
    return rgb, face_box, coarse, GRID_STEP, dict(live=live, **settings)


@pytest.mark.parametrize("affine", [True, False])
def test_person_gain_matches_its_numpy_twin(frame_path, clip, affine):
    """person_gain (the field's cells: the composite's change as gains, or as G f + B) against its
    NumPy twin, with the person's grid, gated and not, on a smaller copy of the frame."""
    from relight.kernels.composite_twin import person_gain_numpy

    from .test_composite import _layer_numpy, _person_grid

    _, frames = clip
    fp = frame_path
    rng = np.random.default_rng(11)
    rgb, face_box, coarse, step, settings = _face_setup(fp, frames, rng)
    h, w = rgb.shape[:2]
    img = cv2.resize(rgb, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    layer = _layer_numpy(fp, rotation_matrix(10, -5, 2), **settings)
    grid = _person_grid(rng, (h // 8, w // 8))
    box = (1, 2, img.shape[1] - 2, img.shape[0] - 1)
    for person, gate in ((grid, False), (grid, True), (None, False)):
        kw = dict(mode="live", scale=(2.0, 2.0), person=person, frame_size=(w, h), floor=0.02, gate=gate)
        got = fp.compositor.person_gain(img, box, face_box, coarse, step, affine=affine, **kw)
        want = person_gain_numpy(img, box, face_box, coarse, step, fp.rig.origin, layer, affine=affine, **kw)
        assert (want[..., 3] > 0).sum() > 100  # it changes something
        np.testing.assert_array_equal(got[..., 3] > 0, want[..., 3] > 0)
        on = want[..., 3] > 0
        for lo, hi in ((0, 3), (4, 7)):
            d = np.abs(got[..., lo:hi] - want[..., lo:hi])[on]
            assert np.quantile(d, 0.999) <= FIELD_TWIN_REL * max(float(np.abs(want[..., lo:hi]).max()), 1e-3)
        if affine:  # the field's code maps (field_cells) against code_grid, for RGB and for planes
            from relight.engine.field import code_grid
            from relight.video_yuv import _TO_RGB, _TO_YCBCR

            colour = img[box[1]:box[3], box[0]:box[2]]
            for maps in ((None, None), (_TO_RGB, _TO_YCBCR)):
                cells = fp.compositor.person_gain(img, box, face_box, coarse, step, code_maps=maps, **kw)
                twin = code_grid(want, colour, *maps)
                d = np.abs(cells - twin)[on]
                assert np.quantile(d, 0.999) <= FIELD_CODES_REL * max(float(np.abs(twin).max()), 1.0), d.max()


def test_the_field_at_the_frames_own_scale_is_the_composite(frame_path, clip):
    """The field made on the frame itself (a cell a pixel) and applied to it gives composite_person's
    bytes but for rounding: G f + B is the composite's own value, split."""
    from .test_composite import _person_grid

    _, frames = clip
    fp = frame_path
    rng = np.random.default_rng(12)
    rgb, face_box, coarse, step, _ = _face_setup(fp, frames, rng)
    h, w = rgb.shape[:2]
    grid = _person_grid(rng, (h // 8, w // 8))
    box = (0, 0, w, h)
    kw = dict(mode="live", person=grid, frame_size=(w, h), floor=0.02, gate=True)
    want = fp.compositor.composite_person(rgb, box, face_box, coarse, step, **kw)
    cells = fp.compositor.person_gain(rgb, box, face_box, coarse, step, code_maps=(None, None), **kw)
    got = fp.field.applier.rgb(rgb, box, cells, 1, (0, 0))
    diff = np.abs(got.astype(int) - want)
    assert (want != rgb).any(axis=2).sum() > 1000  # it did something
    assert diff.max() <= COMPOSITE_TWIN_CODES and (diff > 0).mean() < 0.01


def test_a_carried_field_moves_with_the_head():
    """LightField.moved: a field carried by (dx, dy) whole pixels, applied to the frame moved by as
    much, gives the first result moved by as much."""
    from relight.engine.field import LightField
    from relight.kernels.field_apply import FieldApplier

    rng = np.random.default_rng(4)
    h, w = 90, 160
    rgb = cv2.GaussianBlur(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), (0, 0), 2.0)
    grid = _grid(rng, (12, 16))
    grid[..., 24] = 1.0
    fld = LightField(grid, "rgb", 4, (40.0, 20.0), (36, 16, 108, 72), (70.0, 45.0), 0)
    fa = FieldApplier()
    a = fa.rgb(rgb, fld.box, fld.grid, fld.factor, fld.corner)
    dx, dy = 8, -6  # (a field is carried in whole even pixels)
    moved = np.roll(rgb, (dy, dx), axis=(0, 1))
    carried = fld.moved((70.0 + dx, 45.0 + dy), (w, h))
    b = fa.rgb(moved, carried.box, carried.grid, carried.factor, carried.corner)
    np.testing.assert_array_equal(np.roll(a, (dy, dx), axis=(0, 1))[10:-10, 10:-10], b[10:-10, 10:-10])


def test_a_frames_planes_are_read_and_scaled_as_its_rgb():
    """YuvFrame.small_box (the field's copy: each plane's blocks averaged, then converted) and
    sample_codes (the live light's samples) against the same made from the frame's RGB."""
    from relight.engine.field import small_copy
    from relight.video_yuv import YuvFrame, sample_codes

    rng = np.random.default_rng(9)
    h, w = 96, 160
    rgb = cv2.GaussianBlur(rng.integers(30, 220, (h, w, 3), dtype=np.uint8), (0, 0), 4.0)
    frame = YuvFrame(*_planes(rgb))
    whole = frame.to_rgb()
    for box, f in (((16, 8, 96, 64), 4), ((0, 0, 160, 96), 2), ((144, 88, 168, 100), 4), ((10, 6, 50, 40), 1)):
        a = small_copy(frame, box, f).astype(int)
        b = small_copy(whole, box, f).astype(int)
        assert a.shape == b.shape and np.abs(a - b).mean() < FIELD_SAMPLE_CODES
    xy = rng.uniform([0, 0], [w - 1, h - 1], (200, 2)).astype(np.float32)
    d = np.abs(sample_codes(frame, xy).astype(int) - sample_codes(whole, xy))
    assert d.mean() < FIELD_SAMPLE_CODES
