"""A real face photo nobody here made (scikit-image's `astronaut`) through the video path.

The photo becomes an RTI image set (its pixels as albedo on a smooth dome over the detected
face, lit from 40 directions), `relight capture --images` makes a bundle of it, and short clips
made from the photo (shifted, turned, scaled, brightness-changed) are relit frame by frame: the
face must be found, the change must stay on and around the face, and nothing may crash.
"""

import cv2
import numpy as np
import pytest

from relight.colour import decode_srgb8, encode_srgb8

from .once import made_once
from .tolerances import OUTSIDE_FACE_SHARE

# The RTI set's capture (~30 s) and five clips: `make test-slow`, CI (the detector and the tracker
# keep their own tests in `make test`).
pytestmark = pytest.mark.slow

skimage_data = pytest.importorskip("skimage.data", reason="scikit-image (a test extra) provides the photo")

FRAMES = 12
#: Largest extra jump (sum of RGB codes, 99th percentile) across the face mask's edge.
SEAM_CODES = 30


def _face_box(rgb):
    from relight.engine.face_detect import FaceDetector
    from relight.engine.tracking import face_xywh

    faces = FaceDetector().detect(rgb)
    assert faces, "the face detector should find the astronaut's face"
    return face_xywh(faces[0])


@pytest.fixture(scope="module")
def astronaut_bundle(tmp_path_factory):
    """A bundle captured from 40 images of the photo shaded by a height field (an RTI set made
    once per run: pytest-xdist's workers share it)."""
    from relight import load_bundle
    from relight.imageio import write_image
    from relight.pipeline.capture import capture

    photo = skimage_data.astronaut()

    def make(root):
        x, y, w, h = _face_box(photo)
        cx, cy = x + w / 2, y + 0.55 * h
        rx, ry = 0.62 * w, 0.85 * h
        yy, xx = np.mgrid[0:photo.shape[0], 0:photo.shape[1]].astype(np.float64)
        r2 = ((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2
        inside = r2 < 1.0
        height = np.where(inside, 0.6 * rx * np.sqrt(np.clip(1.0 - r2, 0.0, None)), 0.0)
        gy, gx = np.gradient(height)
        normal = np.dstack([-gx, gy, np.ones_like(gx)])
        normal /= np.linalg.norm(normal, axis=2, keepdims=True)
        albedo = decode_srgb8(photo)
        folder = root / "astronaut_rti"
        folder.mkdir()
        rng = np.random.default_rng(5)
        lines = []
        for i in range(40):
            d = rng.normal(size=3)
            d[2] = abs(d[2]) + 0.6
            d /= np.linalg.norm(d)
            shade = np.clip(normal @ d, 0.0, None)[..., None]
            img = albedo * (0.9 * shade + 0.02)
            name = f"img{i:02d}.png"
            write_image(folder / name, encode_srgb8(np.clip(img, 0, 1)))
            lines.append(f"{name} {d[0]:.6f} {d[1]:.6f} {d[2]:.6f}")
        (folder / "dirs.lp").write_text(f"{len(lines)}\n" + "\n".join(lines) + "\n")
        write_image(folder / "mask.png", (inside * 255).astype(np.uint8))
        capture(folder, root / "astronaut.bundle", images=True, progress=False)

    return load_bundle(made_once(tmp_path_factory, "astronaut-bundle", make) / "astronaut.bundle"), photo


def _clip(photo, kind):
    h, w = photo.shape[:2]
    frames = []
    for i in range(FRAMES):
        s = i / (FRAMES - 1)
        angle, scale, shift, gain = 0.0, 1.0, (0.0, 0.0), 1.0
        if kind == "shifted":
            shift = (40 * s, -25 * s)
        elif kind == "turned":
            angle = 14 * np.sin(2 * np.pi * s)
        elif kind == "scaled":
            scale = 1.0 + 0.2 * np.sin(2 * np.pi * s)
        elif kind == "brightness":
            gain = 0.6 + 0.8 * s
        elif kind == "leaving":  # the face slides out of the frame: partly, then wholly
            shift = (-0.85 * w * s, 0.0)
        m = cv2.getRotationMatrix2D((w / 2, h / 2), angle, scale)
        m[:, 2] += shift
        border = cv2.BORDER_CONSTANT if kind == "leaving" else cv2.BORDER_REFLECT
        f = cv2.warpAffine(photo, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=border)
        if gain != 1.0:
            f = encode_srgb8(np.clip(decode_srgb8(f) * gain, 0, 1))
        frames.append((f, m))
    return frames


@pytest.mark.parametrize(("kind", "mode"), [("shifted", "transfer"), ("turned", "paste"), ("scaled", "transfer"),
                                           ("brightness", "paste"), ("leaving", "transfer")])
def test_astronaut_clips_track_and_composite(astronaut_bundle, kind, mode, tmp_path):
    from relight import load_environment
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings
    from relight.imageio import write_image

    bundle, photo = astronaut_bundle
    # region face: this checks where the face's composite lands (the person's hair and shoulders
    # would change too in region person)
    fp = FramePath(bundle, load_environment("builtin:window"), FrameSettings(mode=mode, region="face"))
    face = cv2.dilate(np.asarray(bundle.mask, np.uint8), np.ones((31, 31), np.uint8))
    found = 0
    sheet = []
    for i, (f, m) in enumerate(_clip(photo, kind)):
        out, info = fp.process(f, i / 30)
        assert out.shape == f.shape and out.dtype == np.uint8
        found += info.face
        changed = np.abs(out.astype(int) - f.astype(int)).sum(axis=2) > 3
        if info.face:
            # The change stays on the face where the clip put it (the reference mask moved the
            # same way, generously dilated).
            where = cv2.warpAffine(face, m, (f.shape[1], f.shape[0]), flags=cv2.INTER_NEAREST) > 0
            assert changed.sum() > 500
            assert (changed & ~where).sum() <= OUTSIDE_FACE_SHARE * changed.sum()
            # No seam: the relit layer blends in, no pixel jumps across the mask's edge.
            edge = cv2.morphologyEx(where.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
            jump_out = np.abs(np.diff(out.astype(int), axis=1)).sum(axis=2)[edge[:, 1:]]
            jump_in = np.abs(np.diff(f.astype(int), axis=1)).sum(axis=2)[edge[:, 1:]]
            assert np.percentile(jump_out, 99) <= np.percentile(jump_in, 99) + SEAM_CODES
        else:
            assert not changed.any()
        if i in (0, FRAMES // 2, FRAMES - 1):
            sheet.append(np.concatenate([f, out], axis=1))
    if kind == "leaving":
        assert 3 <= found < FRAMES  # found while it is in the frame, not after it left
    else:
        assert found >= FRAMES - 2
    write_image(tmp_path / f"astronaut_{kind}_{mode}.png", np.concatenate(sheet, axis=0))
