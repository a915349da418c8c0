"""Video colour: tags read, curves and primaries against published values, Y'CbCr against
FFmpeg's swscale, HDR kept above 1, gamut mapped, and every kind of phone file decoded."""

from __future__ import annotations

import numpy as np
import pytest

from relight.video_colour import (
    PLANAR_FORMATS,
    VideoColour,
    colour_from_tags,
    decode_planes,
    from_linear,
    gamut_map,
    luma_table,
    primaries_to_rec709,
    to_linear,
    tonemap,
)

from .phone_video import encode_like_phone, linear_to_codes
from .tolerances import CURVE_REL, DISPLAY_MATRIX_CODES, F32_CLOSE, F32_EXACT, F64_EXACT

#: Published reference values are given to 4 decimals.
PUBLISHED_TOL = 2e-4
#: One 10-bit code of the signal (a linear curve here), with rounding on both sides.
TEN_BIT_CODE = 1.5 / 876.0
#: A 10-bit code step in linear light near reference white is ~0.3 %; 4:2:0 chroma and the
#: encoder add the rest.
ROUND_TRIP_REL = 0.01


def test_pq_and_hlg_against_bt2408_reference_points():
    # ST 2084: 100 cd/m^2 at signal 0.5081, 203 (BT.2408 reference white) at 0.5806, 1000 at 0.7518.
    nits = to_linear(np.array([0.5081, 0.5806, 0.7518, 1.0]), "pq") * 203.0
    np.testing.assert_allclose(nits, [100.0, 203.0, 1000.0, 10000.0], rtol=CURVE_REL)
    # HLG: the 75 % signal is reference white (1.0); 0.5 is 1/12 of the scene peak.
    hlg = to_linear(np.array([0.75, 0.5, 1.0]), "hlg")
    assert abs(hlg[0] - 1.0) < 1e-9
    np.testing.assert_allclose(hlg[1] / hlg[2], 1.0 / 12.0, rtol=CURVE_REL)
    assert hlg[2] > 3.5  # HDR: the peak is well above reference white, and kept
    # sRGB and BT.709 at known points.
    np.testing.assert_allclose(to_linear(np.array([0.5, 1.0]), "srgb"), [0.21404, 1.0], atol=F32_CLOSE)
    # BT.709's inverse OETF with the spec's rounded constants (1.099, 0.099, 4.5 below 0.081).
    np.testing.assert_allclose(to_linear(np.array([0.04, 0.5]), "bt709"), [0.04 / 4.5, (0.599 / 1.099) ** (1 / 0.45)],
                               atol=PUBLISHED_TOL)


@pytest.mark.parametrize("transfer", ["srgb", "bt709", "gamma22", "linear", "pq", "hlg"])
def test_every_curve_inverts(transfer):
    x = np.linspace(0.0, 1.0 if transfer not in ("pq", "hlg") else 3.5, 50)
    back = to_linear(from_linear(x, transfer), transfer)
    np.testing.assert_allclose(back, x, atol=F32_EXACT, rtol=F32_EXACT)  # float32 sRGB


def test_primaries_match_the_published_matrices():
    # ITU-R BT.2087: linear BT.709 -> BT.2020.
    bt2087 = np.array([[0.6274, 0.3293, 0.0433], [0.0691, 0.9195, 0.0114], [0.0164, 0.0880, 0.8956]])
    np.testing.assert_allclose(np.linalg.inv(primaries_to_rec709("bt2020")), bt2087, atol=PUBLISHED_TOL)
    # Display P3 -> sRGB (D65 both).
    p3 = np.array([[1.2249, -0.2249, 0.0], [-0.0421, 1.0421, 0.0], [-0.0196, -0.0786, 1.0983]])
    np.testing.assert_allclose(primaries_to_rec709("p3"), p3, atol=PUBLISHED_TOL)
    np.testing.assert_allclose(primaries_to_rec709("bt2020").sum(axis=1), 1.0, atol=F64_EXACT)  # white stays white


def test_colours_outside_rec709_keep_luminance_and_hue_without_negatives():
    from relight.colour import LUMINANCE

    # Pure BT.2020 green is far outside Rec.709.
    rgb = (primaries_to_rec709("bt2020") @ np.array([0.0, 0.5, 0.0])).astype(np.float32)[None]
    assert rgb.min() < 0
    before = float(rgb[0] @ LUMINANCE)
    out = gamut_map(rgb.copy())
    assert out.min() >= 0 and np.isfinite(out).all()
    assert abs(float(out[0] @ LUMINANCE) - before) < 1e-6
    assert np.argmax(out[0]) == 1  # still green


@pytest.mark.parametrize("matrix,full", [("bt2020", False), ("bt709", True), ("bt601", False)])
def test_ten_bit_ycbcr_matches_swscale(matrix, full):
    """The NumPy Y'CbCr -> R'G'B' of 10-bit planes against FFmpeg's own conversion to 16-bit RGB."""
    import av
    from av.video.reformatter import ColorRange, Colorspace

    from relight.video_frame import crop_frame, sws_flags

    h, w = 32, 48
    colour = VideoColour(matrix=matrix, primaries="bt709", transfer="linear", full_range=full, bits=10)
    # Smooth colours: chroma upsampling filters agree on them to well under a 10-bit code.
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    lin = np.stack([0.1 + 0.8 * xx, 0.2 + 0.6 * yy, 0.9 - 0.7 * xx * yy], axis=-1)
    y, u, v = linear_to_codes(lin, colour, subsample=False)  # 4:4:4: the chroma filters play no part
    frame = av.VideoFrame.from_ndarray(np.stack([y, u, v], axis=-1) << 6, format="yuv444p16le")
    frame = frame.reformat(format="yuv444p10le")
    assert np.array_equal(crop_frame(frame, (0, 0, w, h)).y, y)
    frame.colorspace, frame.color_range = {"bt2020": 9, "bt709": 1, "bt601": 6}[matrix], 2 if full else 1
    frame.color_trc, frame.color_primaries = 8, 1
    cs = {"bt2020": Colorspace.BT2020, "bt709": Colorspace.ITU709, "bt601": Colorspace.SMPTE170M}[matrix]
    rng = ColorRange.JPEG if full else ColorRange.MPEG
    ref = frame.reformat(format="rgb48le", src_colorspace=cs, src_color_range=rng, dst_color_range=ColorRange.JPEG,
                         interpolation=sws_flags()).to_ndarray().astype(np.float64) / 65535.0
    ours = crop_frame(frame, (0, 0, w, h)).linear()
    got = crop_frame(frame, (0, 0, w, h)).colour
    assert (got.matrix, got.full_range, got.bits, got.transfer) == (matrix, full, 10, "linear")
    np.testing.assert_allclose(ours, lin, atol=TEN_BIT_CODE)
    # swscale's limited-range path reads ~2 codes dark everywhere (measured: mean -0.0019 at
    # 10 bits, where ours is within a code of the truth); beyond that offset the two agree.
    d = (ours - ref).reshape(-1, 3)
    assert np.abs(d.mean(axis=0)).max() < 3 * TEN_BIT_CODE
    assert np.abs(d - d.mean(axis=0)).max() < 2 * TEN_BIT_CODE


def test_tags_missing_or_contradictory_give_notes_not_errors():
    untagged = colour_from_tags("yuv420p", 2, 2, 2, 0, 1080)
    assert (untagged.matrix, untagged.primaries, untagged.transfer, untagged.full_range) == \
        ("bt709", "bt709", "srgb", False) and not untagged.notes
    assert colour_from_tags("yuv420p", 2, 2, 2, 0, 480).matrix == "bt601"
    assert colour_from_tags("yuvj420p", 1, 1, 1, 0, 480).full_range
    hdr8 = colour_from_tags("yuv420p", 1, 1, 18, 1, 1080)  # HLG in 8 bits with BT.709 primaries
    assert hdr8.transfer == "hlg" and any("banding" in n for n in hdr8.notes) and \
        any("primaries" in n for n in hdr8.notes)
    odd = colour_from_tags("yuv420p10le", 8, 22, 17, 1, 1080)  # YCgCo, EBU 3213, SMPTE 428: unsupported
    assert (odd.matrix, odd.primaries, odd.transfer) == ("bt709", "bt709", "srgb") and len(odd.notes) == 3
    assert colour_from_tags("yuv420p10le", 9, 9, 18, 1, 2160).notes == ()  # iPhone HDR: clean
    assert set(PLANAR_FORMATS) >= {"yuv420p", "yuv420p10le"}


def test_luma_table_and_tonemap():
    hlg = VideoColour(matrix="bt2020", primaries="bt2020", transfer="hlg", bits=10)
    lut = luma_table(hlg)
    assert lut.shape == (1024,) and lut[64] == 0.0 and abs(lut[940] - to_linear(np.array(1.0), "hlg")) < 1e-4
    assert np.all(np.diff(lut[64:941]) > 0)
    x = np.array([0.0, 0.5, 0.8, 1.0, 2.0, 100.0], dtype=np.float32)
    t = tonemap(x)
    np.testing.assert_allclose(t[:3], x[:3])
    assert np.all(np.diff(t) > 0) and t[-1] <= 1.0


def test_decode_planes_keeps_hdr_above_reference_white():
    colour = VideoColour(matrix="bt2020", primaries="bt2020", transfer="pq", bits=10)
    lin = np.full((4, 4, 3), 3.0)  # 609 cd/m^2: three times reference white
    y, u, v = linear_to_codes(lin, colour)
    out = decode_planes(y, u.repeat(2, 0).repeat(2, 1), v.repeat(2, 0).repeat(2, 1), colour)
    np.testing.assert_allclose(out, 3.0, rtol=ROUND_TRIP_REL)


@pytest.mark.parametrize("codec,colour", [
    ("libx265", VideoColour(matrix="bt2020", primaries="bt2020", transfer="hlg", bits=10)),
    ("libx265", VideoColour(matrix="bt2020", primaries="bt2020", transfer="pq", bits=10)),
    ("libx264", VideoColour(matrix="bt709", primaries="bt709", transfer="bt709", bits=8, full_range=True)),
    ("libvpx-vp9", VideoColour(matrix="bt601", primaries="bt709", transfer="srgb", bits=8)),
    ("libsvtav1", VideoColour(matrix="bt709", primaries="p3", transfer="srgb", bits=10)),
])
def test_phone_codecs_decode_to_the_same_linear_light(tmp_path, codec, colour):
    """A clip written by each codec with each tag set reads back (through every reader) as the
    linear light that was encoded."""
    import av

    from relight.colour import decode_srgb8, encode_srgb8
    from relight.video_frame import crop_frame
    from relight.video_read import read_frames, read_frames_raw, read_luma
    from relight.video_write import VideoWriter

    try:
        av.codec.Codec(codec, "w")
    except Exception:  # noqa: BLE001 - which encoders a wheel carries varies
        pytest.skip(f"the FFmpeg in this PyAV wheel has no {codec} encoder")
    h, w = 96, 128
    # Smooth colours across the gamut's inside (sharp edges would measure the codecs' chroma
    # filters, not the decoding).
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    base = np.stack([0.05 + 0.85 * xx, 0.05 + 0.85 * yy, 0.9 - 0.8 * xx * (1 - yy)], axis=-1).astype(np.float32)
    src = tmp_path / "src.mp4"
    with VideoWriter(src, 30, (w, h), crf=0) as wr:
        for _ in range(3):
            wr.write(encode_srgb8(base))
    out = encode_like_phone(src, tmp_path / ("phone.mkv" if codec != "libx265" else "phone.mp4"), colour,
                            codec=codec, lossless=True)
    truth = decode_srgb8(next(read_frames(src)))
    lin = crop_frame(next(read_frames_raw(out)), (0, 0, w, h)).linear()
    inner = (slice(4, -4), slice(4, -4))
    rel = (np.abs(lin - truth) / np.maximum(truth, 0.05))[inner]
    assert np.median(rel) < ROUND_TRIP_REL and np.percentile(rel, 99) < 3 * ROUND_TRIP_REL, rel.max()
    shown = next(read_frames(out))
    assert shown.shape == (h, w, 3)
    if colour.transfer != "bt709":  # 8-bit BT.709-curve codes are shown as they are, as players do
        assert np.abs(shown.astype(int) - next(read_frames(src)).astype(int))[inner].mean() < DISPLAY_MATRIX_CODES
    assert next(read_luma(out)).shape == (h, w)


def test_curves_primaries_and_ycbcr_match_colour_science():
    """relight's hand-written HLG, PQ, BT.709, sRGB and gamma curves, its primaries matrices and
    its Y'CbCr decode agree with colour-science's (an independent implementation of the same
    standards) on dense grids, every range and bit depth."""
    import colour

    from relight.video_colour import ycbcr_matrix

    e = np.linspace(0.0, 1.0, 4097)
    hlg_white = colour.models.oetf_inverse_BT2100_HLG(0.75)
    refs = {"hlg": colour.models.oetf_inverse_BT2100_HLG(e) / hlg_white,
            "pq": colour.models.eotf_BT2100_PQ(e) / 203.0,
            "bt709": colour.models.oetf_inverse_BT709(e),
            "srgb": colour.models.eotf_sRGB(e),
            "gamma22": colour.models.gamma_function(e, 2.2),
            "linear": e}
    for transfer, ref in refs.items():
        np.testing.assert_allclose(to_linear(e, transfer), ref, rtol=CURVE_REL, atol=F64_EXACT, err_msg=transfer)
    for ours, theirs in (("bt2020", "ITU-R BT.2020"), ("p3", "Display P3"), ("bt709", "ITU-R BT.709")):
        m = colour.matrix_RGB_to_RGB(colour.RGB_COLOURSPACES[theirs], colour.RGB_COLOURSPACES["ITU-R BT.709"])
        np.testing.assert_allclose(primaries_to_rec709(ours), m, atol=F64_EXACT, err_msg=ours)
    rng = np.random.default_rng(1)
    rgb = rng.uniform(0.0, 1.0, (500, 3))
    for matrix, weights in (("bt709", "ITU-R BT.709"), ("bt601", "ITU-R BT.601"), ("bt2020", "ITU-R BT.2020")):
        for bits in (8, 10, 12):
            for full in (False, True):
                vc = VideoColour(matrix=matrix, bits=bits, full_range=full)
                codes = colour.RGB_to_YCbCr(rgb, K=colour.WEIGHTS_YCBCR[weights], out_bits=bits, out_legal=not full,
                                            out_int=True).astype(np.float64)
                back = np.hstack([codes, np.ones((len(codes), 1))]) @ ycbcr_matrix(vc).astype(np.float64).T
                want = colour.YCbCr_to_RGB(codes, K=colour.WEIGHTS_YCBCR[weights], in_bits=bits, in_legal=not full,
                                           in_int=True)
                np.testing.assert_allclose(back, want, atol=F32_CLOSE, err_msg=f"{matrix} {bits} {full}")
