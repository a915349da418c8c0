"""The key light placed by hand (``builtin:key:...``, :mod:`relight.key_light`): its colour against
an independent colorimetry library, its power, its fields' checks, and what it does to a face."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from relight import load_environment
from relight.colour import LUMINANCE
from relight.errors import InputError
from relight.key_light import DEFAULTS, RANGES, KeyLight, direction, kelvin_rgb

from .lights import white_reading
from .tolerances import KELVIN_XY_TOL, KEY_POWER_REL


def _reference_rgb(kelvin: float) -> np.ndarray:
    """The light's colour by colour-science (an independent implementation): the Planckian locus
    (Kang 2002) below 4000 K, the CIE daylight locus from 5000 K, in linear Rec.709, luminance 1."""
    import colour

    if kelvin < 4000:
        xy = colour.temperature.CCT_to_xy_Kang2002(kelvin)
    else:
        xy = colour.temperature.CCT_to_xy_CIE_D(kelvin)
    rgb = colour.XYZ_to_RGB(colour.xy_to_XYZ(xy), colour.RGB_COLOURSPACES["ITU-R BT.709"])
    return rgb / (LUMINANCE @ rgb)


@pytest.mark.parametrize("kelvin", [1900, 2700, 3500, 5000, 5600, 8000, 12000])
def test_colour_temperature_matches_colorimetry(kelvin):
    """kelvin_rgb against colour-science: the same chromaticity (after 6500 K's small step to D65
    is taken out of both) and luminance 1; warmer is redder, and 6500 K is neutral exactly."""
    ours = kelvin_rgb(kelvin)
    ref = _reference_rgb(kelvin) / _reference_rgb(6500)
    ref = ref / (LUMINANCE @ ref)
    assert abs(float(LUMINANCE @ ours) - 1.0) < 1e-9
    # compare chromaticities (r/sum, g/sum): the luminance is already equal
    np.testing.assert_allclose(ours[:2] / ours.sum(), ref[:2] / ref.sum(), atol=KELVIN_XY_TOL)
    np.testing.assert_allclose(kelvin_rgb(6500), [1.0, 1.0, 1.0], atol=1e-12)
    reds = [kelvin_rgb(k)[0] / kelvin_rgb(k)[2] for k in (2000, 3000, 4500, 6500, 9000)]
    assert all(a > b for a, b in zip(reds, reds[1:], strict=False))


def test_directions_follow_the_camera_convention():
    """az toward +X (the image's right), el toward +Y (up), (0, 0) toward the camera (+Z)."""
    np.testing.assert_allclose(direction(0, 0), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(direction(90, 0), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(direction(0, 90), [0, 1, 0], atol=1e-12)
    env = load_environment("builtin:key:az=40,el=20,fill=0,size=4", width=256)
    lum = env @ LUMINANCE
    v, u = np.unravel_index(np.argmax(lum), lum.shape)
    from relight.directions import equirect_directions

    d = equirect_directions(256, 128)[v, u]
    assert np.degrees(np.arccos(np.clip(d @ direction(40, 20), -1, 1))) < 3.0


@pytest.mark.parametrize("power", [0.5, 1.0, 3.0])
def test_a_key_is_as_strong_as_its_power_in_flashes(power):
    """A white Lambertian surface facing the key reads ``power`` (as a capture flash reads 1) plus
    the ambient; the fill adds ``fill`` x the key's power where it faces the fill."""
    key = KeyLight(az=30, el=25, size=6, kelvin=6500, fill=0.0, power=power)
    env = key.environment(512)
    ambient = 0.05 * power  # AMBIENT: the half of the sphere facing the surface, radiance 0.05 power
    got = white_reading(env, direction(30, 25))
    assert got == pytest.approx(power + ambient, rel=KEY_POWER_REL)
    with_fill = KeyLight(az=30, el=25, size=6, kelvin=6500, fill=0.5, power=power).environment(512)
    extra = white_reading(with_fill, direction(-30, 12.5)) - white_reading(env, direction(-30, 12.5))
    assert extra == pytest.approx(0.5 * power, rel=0.05)  # the fill is wide: its cosine falls off inside it


def test_fields_parse_round_trip_and_defaults():
    assert KeyLight.parse("") == KeyLight() == KeyLight(**DEFAULTS)
    k = KeyLight.parse(" az = -45, kelvin=3200,size=12 ")
    assert (k.az, k.kelvin, k.size, k.el) == (-45.0, 3200.0, 12.0, DEFAULTS["el"])
    assert KeyLight.parse(k.spec()[len("key:"):]) == k
    a = load_environment("builtin:key")
    b = load_environment("builtin:key:" + KeyLight().spec()[len("key:"):])
    assert np.array_equal(a, b) and a.dtype == np.float32 and np.isfinite(a).all() and a.min() >= 0


@pytest.mark.parametrize("spec, words", [
    ("az=200", ["az", "-180", "180"]),
    ("el=-91", ["el", "-90", "90"]),
    ("size=0", ["size", "1", "120"]),
    ("kelvin=900", ["kelvin", "1700", "25000"]),
    ("kelvin=warm", ["kelvin", "1700"]),
    ("fill=2", ["fill", "0", "1"]),
    ("power=0", ["power", "0.01", "100"]),
    ("power=nan", ["power"]),
    ("power=inf", ["power"]),
    ("colour=5", ["colour", "az, el, size, kelvin, fill, power"]),
    ("az=10,az=20", ["az", "twice"]),
    ("az", ["name=value"]),
])
def test_bad_fields_name_the_field_and_its_range(spec, words):
    with pytest.raises(InputError) as err:
        load_environment("builtin:key:" + spec)
    for w in words:
        assert w in str(err.value), (spec, str(err.value))


def test_every_range_is_checked_at_both_ends():
    for name, (lo, hi) in RANGES.items():
        KeyLight(**{name: lo})
        KeyLight(**{name: hi})
        for bad in (lo - 1e-6 * max(1.0, abs(lo)) - 1e-9, hi + 1e-6 * max(1.0, abs(hi))):
            with pytest.raises(InputError, match=name):
                KeyLight(**{name: bad})


@pytest.fixture(scope="module")
def face(small_bundle):
    """(relight(spec) -> (H, W, 3) linear image of the small bundle's face, the face's mask)."""
    from relight.kernels.relighter import Relighter

    r = Relighter(small_bundle)

    def relight(spec: str) -> np.ndarray:  # a key light's fields, or an environment's whole name
        source = spec if spec.startswith("builtin:") else "builtin:key:" + spec
        return np.asarray(r.relight(load_environment(source)), dtype=np.float64)

    return relight, small_bundle.mask


def test_a_key_from_the_right_lights_the_right_half(face):
    """A key from az=60 lights the face's image-right half more than its left; az=-60 the
    opposite."""
    relight, mask = face
    cols = np.nonzero(mask.any(axis=0))[0]
    right = np.arange(mask.shape[1])[None, :] > (cols.min() + cols.max()) / 2
    for az, brighter in ((60, "right"), (-60, "left")):
        lum = relight(f"az={az}") @ LUMINANCE
        r, left = lum[mask & right].mean(), lum[mask & ~right].mean()
        assert (r > 1.3 * left) if brighter == "right" else (left > 1.3 * r), (az, r, left)


def test_a_warm_key_gives_a_redder_face(face):
    relight, mask = face
    ratio = {k: relight(f"kelvin={k}")[mask].sum(axis=0) for k in (2700, 6500)}
    rb = {k: v[0] / v[2] for k, v in ratio.items()}
    assert rb[2700] > 2.0 * rb[6500], rb


def test_a_wider_key_softens_the_shadow_edge_of_the_nose(face):
    """The steepest change of shading in the middle of the face (the nose and its cast shadow)
    under a side key - the log of the face's luminance over its luminance under uniform light,
    which takes out the skin's own edges (brows, eyes, lips) - a 60-degree key's is well below
    a 5-degree key's."""
    relight, mask = face
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    inner = cv2.erode(mask.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    h, w = rows.max() - rows.min(), cols.max() - cols.min()
    box = np.zeros_like(mask)
    box[rows.min() + h // 3: rows.max() - h // 3, cols.min() + w // 3: cols.max() - w // 3] = True
    steep = {}
    flat = np.maximum(relight("builtin:uniform") @ LUMINANCE, 1e-4)
    for size in (5, 60):
        lit = np.maximum(relight(f"az=70,el=10,fill=0,size={size}") @ LUMINANCE, 1e-4)
        lum = np.log(lit / flat).astype(np.float32)
        g = np.hypot(cv2.Sobel(lum, cv2.CV_32F, 1, 0), cv2.Sobel(lum, cv2.CV_32F, 0, 1)) / 8
        steep[size] = float(np.quantile(g[inner & box], 0.99))
    assert steep[60] < 0.85 * steep[5], steep


@pytest.mark.slow  # a capture of a real face set (~15 s): `make test-slow`, CI
def test_the_key_and_a_photo_light_a_real_face_as_they_say(shared_data, tmp_path):
    """On a real face (Extended Yale B, captured from its photos): a key from the image's right
    lights its right half more, a wider key softens the shading's steepest edges in the middle of
    the face, and a photo bright on its left lights it from the left."""
    from PIL import Image

    from relight import load_bundle
    from relight.cli import main
    from relight.colour import linear_to_srgb
    from relight.kernels.relighter import Relighter

    out = tmp_path / "face.bundle"
    assert main(["capture", "--images", str(shared_data / "faces-yale" / "yaleB03"), "--transfer", "linear",
                 "-o", str(out), "--quiet"]) == 0
    bundle = load_bundle(out)
    r, mask = Relighter(bundle), np.asarray(bundle.mask, bool)

    def relight(source):
        return np.asarray(r.relight(load_environment(source)), dtype=np.float64)

    cols = np.nonzero(mask.any(axis=0))[0]
    right = np.arange(mask.shape[1])[None, :] > (cols.min() + cols.max()) / 2

    def right_over_left(img):
        lum = img @ LUMINANCE
        return lum[mask & right].mean() / lum[mask & ~right].mean()

    assert right_over_left(relight("builtin:key:az=60")) > 1.5
    assert right_over_left(relight("builtin:key:az=-60")) < 1 / 1.5
    photo = np.full((300, 400, 3), 0.04, np.float32)
    photo[:, :200] = 0.5
    Image.fromarray((linear_to_srgb(photo) * 255 + 0.5).astype(np.uint8)).save(tmp_path / "left.jpg", quality=95)
    assert right_over_left(relight(f"photo:{tmp_path / 'left.jpg'}")) < 1 / 1.5
    rows = np.nonzero(mask.any(axis=1))[0]
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    h, w = rows.max() - rows.min(), cols.max() - cols.min()
    box = np.zeros_like(mask)
    box[rows.min() + h // 3: rows.max() - h // 3, cols.min() + w // 3: cols.max() - w // 3] = True
    flat = np.maximum(relight("builtin:uniform") @ LUMINANCE, 1e-4)
    steep = {}
    for size in (5, 60):
        lum = np.log(np.maximum(relight(f"builtin:key:az=70,el=10,fill=0,size={size}") @ LUMINANCE, 1e-4) / flat)
        g = np.hypot(cv2.Sobel(lum.astype(np.float32), cv2.CV_32F, 1, 0),
                     cv2.Sobel(lum.astype(np.float32), cv2.CV_32F, 0, 1)) / 8
        steep[size] = float(np.quantile(g[inner & box], 0.99))
    assert steep[60] < 0.85 * steep[5], steep


@pytest.mark.parametrize("az, el", [(0, 0), (45, 20), (-60, -10), (20, 60)])
def test_the_lit_balls_bright_spot_is_where_the_key_is(az, el):
    """relight live's light preview: the grey ball's brightest point under a key light with no fill
    is toward the key, and ball_direction reads the key's direction back from that point (what a
    drag on the page does)."""
    from relight.light_preview import ball_direction, balls

    size = 96
    img = balls(load_environment(f"builtin:key:az={az},el={el},fill=0,size=10", width=256), size)
    assert img.shape == (size, 2 * size, 3) and img.dtype == np.uint8
    grey = img[:, :size].astype(float).mean(axis=2)
    v, u = np.unravel_index(np.argmax(grey), grey.shape)
    got = direction(*ball_direction((u + 0.5) / size, (v + 0.5) / size))
    assert np.degrees(np.arccos(np.clip(got @ direction(az, el), -1, 1))) < 8.0
    skin = img[:, size:].reshape(-1, 3).astype(float)
    assert skin[:, 0].mean() > skin[:, 2].mean()  # the skin ball is skin-toned
