"""How a decoded video frame is shown: the display orientation (quarter turns and a mirror) its
container's display matrix gives, applied to an image (:func:`orient`) or undone for a region
(:func:`coded_box`)."""

from __future__ import annotations

import numpy as np


def display_orientation(frame) -> tuple[int, bool]:
    """How a decoded frame is shown: (quarter turns counter-clockwise, then mirror left-right),
    from the display matrix its container carries (phones store portrait video as landscape
    frames plus this matrix); (0, False) without one.

    FFmpeg's matrix (``AV_FRAME_DATA_DISPLAYMATRIX``, 16.16 fixed point) is a rotation, possibly
    with one column negated (a mirror); its rotation angle is read as ``av_display_rotation_get``
    does, and a mirrored matrix (negative determinant) is a mirror after the rotation that angle
    implies. Angles that are not a multiple of 90 degrees go to the nearest one.

    A frame may carry side data PyAV cannot name - FFmpeg 8 (the PyAV 18 wheels) adds types 28-31
    (LCEVC, VIEW_ID, 3D_REFERENCE_DISPLAYS: multi-view HEVC as phones' spatial video; EXIF: every
    PNG OpenImageIO writes) that PyAV's ``Type`` enum lacks, and its side-data container then
    refuses the whole frame (``ValueError: 31 is not a valid Type``). Then the rotation is read as
    PyAV reads it for ``frame.rotation`` (FFmpeg's ``av_display_rotation_get`` on the raw side
    data, no container) and a mirror, which only the matrix itself shows, is not seen."""
    data = None
    try:
        entries = list(getattr(frame, "side_data", ()) or ())
    except (ValueError, KeyError, TypeError):  # an entry of a type PyAV cannot name
        return _rotation_only(frame), False
    for sd in entries:
        if str(getattr(sd, "type", "")).endswith("DISPLAYMATRIX"):
            data = bytes(sd)
            break
    if data is None or len(data) < 36:
        return 0, False
    m = np.frombuffer(data[:36], dtype="<i4").astype(np.float64) / 65536.0
    s0, s1 = np.hypot(m[0], m[3]), np.hypot(m[1], m[4])
    if not (s0 > 0 and s1 > 0):
        return 0, False
    angle = -np.degrees(np.arctan2(m[1] / s1, m[0] / s0))  # av_display_rotation_get
    mirror = bool(m[0] * m[4] - m[1] * m[3] < 0)
    if mirror:
        angle = -angle - 180.0
    return int(np.round(angle / 90.0)) % 4, mirror


def _rotation_only(frame) -> int:
    """Quarter turns counter-clockwise from PyAV's ``frame.rotation`` (degrees; 0 without a
    display matrix or on a PyAV without it)."""
    try:
        angle = float(getattr(frame, "rotation", 0) or 0)
    except (ValueError, TypeError):
        return 0
    return int(np.round(angle / 90.0)) % 4 if np.isfinite(angle) else 0


def orient(img: np.ndarray, turns: int, mirror: bool) -> np.ndarray:
    """``img`` (H, W, ...) turned ``turns`` quarter turns counter-clockwise, then mirrored
    left-right when ``mirror`` (see :func:`display_orientation`); a view when nothing changes."""
    out = np.rot90(img, turns % 4) if turns % 4 else img
    return out[:, ::-1] if mirror else out



def coded_box(box: tuple[int, int, int, int], turns: int, mirror: bool,
              coded: tuple[int, int]) -> tuple[int, int, int, int]:
    """The region (x, y, w, h) of the coded frame (size ``coded`` = (W, H)) that a region of the
    displayed frame shows, for a display orientation (:func:`display_orientation`)."""
    x, y, w, h = box
    turns %= 4
    size = coded if turns % 2 == 0 else (coded[1], coded[0])  # the displayed size
    if mirror:
        x = size[0] - x - w
    for _ in range(turns):
        # One counter-clockwise quarter turn undone: a box of the turned image (size (Wr, Hr))
        # is (Wp - y - h, x, h, w) in the image before it (size (Hr, Wr)).
        size = (size[1], size[0])
        x, y, w, h = size[0] - y - h, x, h, w
    return x, y, w, h

