"""Fuzzing the readers of hostile input (bounded here; ``relight bench fuzz`` runs longer), and
the defects it found, each kept as a case."""

from __future__ import annotations

import numpy as np
import pytest

from relight import load_bundle
from relight.bench import fuzz, fuzz_seeds, fuzz_targets
from relight.errors import InputError

from .once import made_once


@pytest.fixture(scope="session")
def seeds(tmp_path_factory, request):
    """The fuzz seeds (a bundle captured from a real face, clips of real photos, ...), made once;
    without ../shared the bundle is the suite's small synthetic one (already made for others)."""
    def make(folder):
        if fuzz.shared_data() is None:
            small = request.getfixturevalue("small_bundle")
            (folder / "seed.bundle").write_bytes(small.path.read_bytes())
        fuzz_seeds.make_seeds(folder)

    return made_once(tmp_path_factory, "fuzz-seeds", make)


@pytest.mark.parametrize("target", sorted(fuzz.TARGETS))
def test_fuzz_target_never_crashes(target, seeds, tmp_path):
    """Mutated real files: every input is accepted or refused with our error (or a 4xx)."""
    work = tmp_path / "work"
    for f in seeds.iterdir():
        if f.is_file():
            (work / f.name).parent.mkdir(exist_ok=True)
            (work / f.name).write_bytes(f.read_bytes())
    res = fuzz.fuzz_target(target, work, fuzz.QUICK_EXAMPLES, seed=0, raise_crash=True)
    assert res.crashes == 0 and res.inputs >= fuzz.QUICK_EXAMPLES, res
    assert res.refused > 0, f"{target}: no input was refused - the mutations do not reach the checks ({res})"
    assert res.accepted + res.refused == res.inputs


def _seed_bundle_file(seeds, tmp_path, path, value):
    f = tmp_path / "crafted.bundle"
    f.write_bytes(fuzz_targets.craft_bundle((seeds / "seed.bundle").read_bytes(), path, value))
    return f


@pytest.mark.parametrize(("path", "value", "says"), [
    (("arrays", "pixels", "dtype"), ["<i4"], "unsupported type"),  # was TypeError (unhashable list)
    (("meta", "crop_origin", 0), 65535, "does not fit"),  # was ValueError in Bundle.mask
    (("meta", "frame_size", 0), 4000, "JPEG"),  # a frame larger than the stored picture
    (("arrays", "normal", "shape"), [7, 3], "does not match"),
])
def test_crafted_bundle_refused_on_load(seeds, tmp_path, path, value, says):
    """A header rewritten with its checksums made right (a crafted file, not a damaged one)."""
    with pytest.raises(InputError, match=says):
        fuzz_targets.use_bundle(load_bundle(_seed_bundle_file(seeds, tmp_path, path, value)))


def test_crafted_recipe_azimuths_refused(seeds, tmp_path):
    """meta.recipe.n_az drove the visibility kernel past its buffer (a segfault in PoCL)."""
    b = load_bundle(_seed_bundle_file(seeds, tmp_path, ("meta", "recipe", "n_az"), 2 ** 63 - 1))
    with pytest.raises(InputError, match="horizon azimuths"):
        fuzz_targets.use_bundle(b)


def test_lp_huge_and_tiny_directions_stay_unit(tmp_path):
    """'1e308 1e308 1e308' overflowed the norm to inf and came out as a zero direction."""
    from relight.pipeline.image_set import read_lp

    f = tmp_path / "dirs.lp"
    f.write_text("3\na.jpg 1e308 1e308 1e308\nb.jpg 1e-320 0 0\nc.jpg 0 0 2\n")
    dirs = np.array([d for _, d in read_lp(f)])
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, rtol=1e-12)
    f.write_text("1\na.jpg 0 0 0\n")
    with pytest.raises(InputError, match="non-zero"):
        read_lp(f)


def test_image_error_text_not_utf8(seeds, tmp_path):
    """OpenImageIO's message quoting a damaged EXR's attribute name is not UTF-8: its binding
    raised UnicodeDecodeError out of our reader."""
    from relight.imageio import read_image

    data = bytearray((seeds / "seed-env.exr").read_bytes())
    name = b"displayWindow\x00box2i\x00"
    i = data.find(name) + len(name) + 4 + 13
    data[i:i] = b"\xf8\xc2\xbe\xcf"  # the window's last bytes run into the next attribute's name
    f = tmp_path / "bad.exr"
    f.write_bytes(bytes(data))
    with pytest.raises(InputError, match="not a readable image"):
        read_image(f)


@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000, '{"env": [1]}' + " " * 5000, "\ud800"])
def test_control_messages_refused(text):
    from relight.service.controls import apply_control, new_settings, parse_control
    from relight.service.errors import ServiceError

    with pytest.raises(ServiceError) as err:
        apply_control(new_settings(), parse_control(text))
    assert err.value.status == 422


def test_video_with_damaged_metadata_or_unknown_codec(seeds, tmp_path):
    """Container tags that are not UTF-8 raised UnicodeDecodeError out of PyAV (now read with
    replacement characters); a stream of a codec FFmpeg has no decoder for raised AttributeError."""
    from relight.video_read import probe_video, read_frames

    data = bytearray((seeds / "seed.mp4").read_bytes())
    tagged = bytearray(data)
    i = tagged.find(b"Lavf")  # the muxer's name in the file's tags
    tagged[i + 1] = 0xB2
    f = tmp_path / "tagged.mp4"
    f.write_bytes(bytes(tagged))
    assert probe_video(f).width == 96 and len(list(read_frames(f))) == 6
    unknown = bytearray(data)
    j = unknown.rfind(b"avc1")  # the sample description's codec
    unknown[j:j + 4] = b"zzzz"
    f = tmp_path / "unknown.mp4"
    f.write_bytes(bytes(unknown))
    with pytest.raises(InputError, match="no decoder"):
        probe_video(f)
