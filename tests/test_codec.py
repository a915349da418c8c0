"""The service's frames over the wire (service/codec.py): a JPEG decoded by libjpeg-turbo through
simplejpeg gives OpenCV's pixels exactly; what it leaves to OpenCV (EXIF, CMYK, a truncated file)
is decoded as before; the frames sent back are JPEGs of the frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

pytest.importorskip("fastapi", reason="the service's extras")

from relight.service import codec  # noqa: E402
from relight.service.codec import JPEG_QUALITY, decode_frame, encode_frame  # noqa: E402
from relight.service.errors import ServiceError  # noqa: E402

#: A frame sent back: its PSNR (dB) against the frame, at most this far below OpenCV's JPEG at the
#: same quality (measured 0.06 dB below on this picture, 1.0 on a 720p video frame: the same
#: library, another RGB -> Y'CbCr rounding).
JPEG_PSNR_BELOW_OPENCV = 2.0


def _picture(h=90, w=160) -> np.ndarray:
    rng = np.random.default_rng(4)
    yy, xx = np.mgrid[0:h, 0:w]
    rgb = np.dstack([xx * 255 / w, yy * 255 / h, 128 + 60 * np.sin(xx / 9.0)]) + rng.normal(0, 6, (h, w, 3))
    return np.clip(rgb, 0, 255).astype(np.uint8)


def _cv2_jpeg(rgb, quality=85) -> bytes:
    return cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()


def _cv2_decoded(data: bytes) -> np.ndarray:
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def test_a_jpeg_frame_decodes_to_opencvs_pixels():
    for data in (_cv2_jpeg(_picture()), _cv2_jpeg(_picture()[..., :1].repeat(3, axis=2)),
                 cv2.imencode(".jpg", _picture()[..., 1])[1].tobytes(),  # a grey JPEG
                 cv2.imencode(".jpg", cv2.cvtColor(_picture(), cv2.COLOR_RGB2BGR),
                              [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()):
        assert codec._decode_plain_jpeg(data) is not None  # (libjpeg-turbo's path, not OpenCV's)
        got = decode_frame(data, "image/jpeg", 10**6)
        assert got.dtype == np.uint8 and got.shape == (90, 160, 3)
        np.testing.assert_array_equal(got, _cv2_decoded(data))


def test_what_simplejpeg_leaves_is_decoded_as_before():
    data = _cv2_jpeg(_picture())
    # an EXIF block (orientation 1) after SOI: OpenCV's path, the same pixels
    exif = (b"Exif\x00\x00MM\x00\x2a\x00\x00\x00\x08\x00\x01\x01\x12\x00\x03\x00\x00\x00\x01\x00\x01\x00\x00"
            b"\x00\x00\x00\x00")
    with_exif = data[:2] + b"\xff\xe1" + (len(exif) + 2).to_bytes(2, "big") + exif + data[2:]
    assert codec._decode_plain_jpeg(with_exif) is None
    np.testing.assert_array_equal(decode_frame(with_exif, "image/jpeg", 10**6), _cv2_decoded(data))
    # a truncated file: simplejpeg's strict mode refuses it, and OpenCV's as before
    with pytest.raises(ServiceError, match="truncated or corrupt"):
        decode_frame(data[:len(data) * 2 // 3], "image/jpeg", 10**6)
    with pytest.raises(ServiceError, match="pixels"):
        decode_frame(data, "image/jpeg", 100)
    with pytest.raises(ServiceError, match="header"):
        decode_frame(b"\xff\xd8" + b"\x00" * 64, "image/jpeg", 10**6)


def test_a_frame_sent_back_is_a_jpeg_of_it():
    rgb = _picture()
    data = encode_frame(rgb[:, ::-1], "image/jpeg")  # (a view: not contiguous)
    assert data[:2] == b"\xff\xd8"
    def psnr(data):
        return 10 * np.log10(255.0 ** 2 / np.mean((_cv2_decoded(data).astype(float) - rgb[:, ::-1]) ** 2))

    assert psnr(data) > psnr(_cv2_jpeg(np.ascontiguousarray(rgb[:, ::-1]), JPEG_QUALITY)) - JPEG_PSNR_BELOW_OPENCV
    png = encode_frame(rgb, "image/png")
    np.testing.assert_array_equal(_cv2_decoded(png), rgb)


#: A JPEG's planes made RGB against libjpeg-turbo's own RGB of it: mean codes apart, at most
#: (measured 0.37-0.45 on this smooth picture, and again after the planes are encoded: the chroma
#: upsampled by another filter).
PLANES_RGB_MEAN = 1.5


def _smooth(h=90, w=160) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    rgb = np.dstack([40 + xx * 180 / w, 60 + yy * 150 / h, 128 + 60 * np.sin(xx / 15.0) * np.cos(yy / 11.0)])
    return np.clip(rgb, 0, 255).astype(np.uint8)


def test_a_plain_jpeg_comes_in_its_planes_and_goes_back_as_they_are():
    import simplejpeg

    from relight.video_yuv import YuvFrame

    rgb = _smooth()
    for sub in ("420", "422"):
        data = simplejpeg.encode_jpeg(rgb, quality=90, colorsubsampling=sub)
        frame = decode_frame(data, "image/jpeg", 10**6, planes=True)
        assert isinstance(frame, YuvFrame) and frame.codes == codec.JPEG_CODES
        assert frame.cy == (2 if sub == "420" else 1)
        assert np.abs(frame.to_rgb().astype(float) - _cv2_decoded(data)).mean() < PLANES_RGB_MEAN
        again = encode_frame(frame, "image/jpeg")
        assert simplejpeg.decode_jpeg_header(again)[3] == sub  # its planes, as they are
        back = _cv2_decoded(again).astype(float)
        assert np.abs(back - _cv2_decoded(data)).mean() < PLANES_RGB_MEAN
        png = encode_frame(frame, "image/png")  # a PNG asked for: made RGB
        np.testing.assert_array_equal(_cv2_decoded(png), frame.to_rgb())
    # what does not come in planes: the RGB path, as without ``planes``
    plain = simplejpeg.encode_jpeg(rgb, quality=90, colorsubsampling="444")
    odd = simplejpeg.encode_jpeg(np.ascontiguousarray(rgb[:, :159]), quality=90, colorsubsampling="420")
    grey = cv2.imencode(".jpg", rgb[..., 1])[1].tobytes()
    for data in (plain, odd, grey):
        got = decode_frame(data, "image/jpeg", 10**6, planes=True)
        assert isinstance(got, np.ndarray)
        np.testing.assert_array_equal(got, decode_frame(data, "image/jpeg", 10**6))
    with pytest.raises(ServiceError, match="truncated or corrupt"):
        data = simplejpeg.encode_jpeg(rgb, quality=90, colorsubsampling="420")
        decode_frame(data[:len(data) // 2], "image/jpeg", 10**6, planes=True)
