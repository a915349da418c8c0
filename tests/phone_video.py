"""Re-encode a synthetic capture the way phones store video (tests' helper).

:func:`encode_like_phone` takes an sRGB video (``relight synth``'s) and writes it again with a
phone's codec, bit depth, colour tags, display rotation and frame timing, computing the
Y'CbCr codes itself from linear light (so the file holds exactly what its tags claim).
:func:`renumbered_truth` gives the matching truth when frames were dropped.

The encoder is the independent reference of relight's decoder (:mod:`relight.video_colour`):
its curves, primaries and Y'CbCr come from colour-science (BT.2100 HLG and PQ, BT.709,
IEC 61966-2-1 sRGB, the BT.709/BT.2020/Display P3 colourspaces, ITU-R Y'CbCr weights and
code ranges), none from relight. The light it encodes is the synthetic camera's linear light,
scene-referred as BT.2100 has an HLG camera record it (the OETF), reference white (sRGB's 1.0)
at BT.2408's 75 % HLG signal and at 203 cd/m^2 in PQ.
"""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import numpy as np

from relight.colour import decode_srgb8
from relight.video_colour import VideoColour
from relight.video_read import read_frames

#: FFmpeg's enum values for the tags written.
_MATRIX_TAG = {"bt709": 1, "bt601": 6, "bt2020": 9}
_PRIMARY_TAG = {"bt709": 1, "bt2020": 9, "p3": 12}
_TRANSFER_TAG = {"srgb": 13, "bt709": 1, "hlg": 18, "pq": 16}
#: colour-science's names of the matrices (Kr, Kb weights) and colourspaces (primaries, D65).
_WEIGHTS = {"bt709": "ITU-R BT.709", "bt601": "ITU-R BT.601", "bt2020": "ITU-R BT.2020"}
_SPACES = {"bt709": "ITU-R BT.709", "bt2020": "ITU-R BT.2020", "p3": "Display P3"}
#: BT.2408's reference white: HLG signal 0.75, PQ 203 cd/m^2.
HLG_REFERENCE_SIGNAL = 0.75
PQ_REFERENCE_NITS = 203.0


def encode_signal(linear: np.ndarray, transfer: str) -> np.ndarray:
    """Linear light (reference white 1.0) -> the transfer curve's 0-1 signal, by colour-science."""
    import colour

    x = np.maximum(np.asarray(linear, dtype=np.float64), 0.0)
    if transfer == "linear":
        return np.minimum(x, 1.0)
    if transfer == "srgb":
        return colour.models.eotf_inverse_sRGB(np.minimum(x, 1.0))
    if transfer == "bt709":
        return colour.models.oetf_BT709(np.minimum(x, 1.0))
    if transfer == "hlg":
        white = colour.models.oetf_inverse_BT2100_HLG(HLG_REFERENCE_SIGNAL)  # scene light of reference white
        with np.errstate(invalid="ignore", divide="ignore"):  # (both of its branches are evaluated everywhere)
            return colour.models.oetf_BT2100_HLG(np.minimum(x * white, 1.0))
    if transfer == "pq":
        return colour.models.eotf_inverse_BT2100_PQ(np.minimum(x * PQ_REFERENCE_NITS, 10000.0))
    raise ValueError(f"no reference encoder for the {transfer!r} curve")


def linear_to_codes(linear: np.ndarray, colour: VideoColour, *,
                    subsample: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear Rec.709 (h, w, 3) -> Y, Cb, Cr code planes of ``colour`` (4:2:0 chroma as 2x2
    means, or 4:4:4 without ``subsample``)."""
    import colour as cs

    rgb = cs.RGB_to_RGB(np.asarray(linear, dtype=np.float64), cs.RGB_COLOURSPACES["ITU-R BT.709"],
                        cs.RGB_COLOURSPACES[_SPACES[colour.primaries]])
    from colour.models.rgb.ycbcr import ranges_YCbCr

    sig = encode_signal(np.maximum(rgb, 0.0), colour.transfer)
    legal = not colour.full_range
    ycc = cs.RGB_to_YCbCr(sig, K=cs.WEIGHTS_YCBCR[_WEIGHTS[colour.matrix]], out_bits=colour.bits, out_legal=legal,
                          out_int=False)
    # colour-science's float code values -> its integer code scale (unrounded: 4:2:0 chroma is
    # averaged first, rounded once)
    f, i = ranges_YCbCr(colour.bits, legal, False), ranges_YCbCr(colour.bits, legal, True)
    yy = i[0] + (ycc[..., 0] - f[0]) * (i[1] - i[0]) / (f[1] - f[0])
    cb, cr = (i[2] + (ycc[..., k] - f[2]) * (i[3] - i[2]) / (f[3] - f[2]) for k in (1, 2))
    h, w = yy.shape
    if subsample:
        cb = cb.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
        cr = cr.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
    top = (1 << colour.bits) - 1
    dtype = np.uint8 if colour.bits == 8 else np.uint16
    return tuple(np.clip(np.round(p), 0, top).astype(dtype) for p in (yy, cb, cr))


def encode_like_phone(src, dst, colour: VideoColour, *, codec: str = "libx265", rotation: int = 0,
                      keep=None, times=None, fps: float | None = None, crf: int = 12,
                      lossless: bool = False) -> Path:
    """Write ``src``'s frames to ``dst`` with ``colour``'s codes and tags.

    rotation : display rotation in degrees (the frames are stored turned the other way, as
    phones store portrait video). keep : frame numbers of ``src`` to write (None: all).
    times : (len(keep),) presentation times in seconds (None: evenly at ``fps``, default the
    source's rate). lossless: the codec's lossless mode where it has one (x264, x265, VP9;
    else ``crf`` 1). Returns ``dst``.
    """
    import av

    from relight.video_read import probe_video

    info = probe_video(src)
    fps = fps or info.fps
    fmt = {8: "yuv420p", 10: "yuv420p10le"}[colour.bits]
    tb = Fraction(1, 90000)
    dst = Path(dst)
    with av.open(str(dst), "w") as c:
        s = c.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
        turned = rotation % 180 != 0
        s.width, s.height = (info.height, info.width) if turned else (info.width, info.height)
        s.pix_fmt = fmt
        s.time_base = tb
        s.codec_context.time_base = tb
        opts = {"crf": str(crf if not lossless else (0 if codec == "libx264" else 1))}
        if codec == "libx265":
            opts["x265-params"] = "log-level=error" + (":lossless=1" if lossless else "")
        if codec == "libvpx-vp9":
            opts = {"lossless": "1"} if lossless else {"crf": str(crf), "b": "0"}
        s.options = opts
        cc = s.codec_context
        cc.colorspace, cc.color_primaries = _MATRIX_TAG[colour.matrix], _PRIMARY_TAG[colour.primaries]
        cc.color_trc, cc.color_range = _TRANSFER_TAG[colour.transfer], 2 if colour.full_range else 1
        if rotation:
            s.set_display_rotation(rotation)
        keep_set = None if keep is None else {int(k): i for i, k in enumerate(keep)}
        for n, rgb in enumerate(read_frames(src)):
            if keep_set is not None and n not in keep_set:
                continue
            i = n if keep_set is None else keep_set[n]
            lin = decode_srgb8(rgb)
            if rotation:
                lin = np.rot90(lin, -(rotation // 90))
            y, u, v = linear_to_codes(np.ascontiguousarray(lin), colour)
            frame = _planar_frame((y, u, v), fmt)
            frame.colorspace, frame.color_primaries = cc.colorspace, cc.color_primaries
            frame.color_trc, frame.color_range = cc.color_trc, cc.color_range
            t = (i / fps) if times is None else float(times[i])
            frame.pts = int(round(t / tb))
            frame.time_base = tb
            for pkt in s.encode(frame):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    return dst


def _planar_frame(planes, fmt: str):
    """A PyAV frame of a planar format filled with ``planes`` (each padded to its line size)."""
    import av

    h, w = planes[0].shape
    frame = av.VideoFrame(w, h, fmt)
    for plane, data in zip(frame.planes, planes, strict=True):
        stride = plane.line_size // data.dtype.itemsize
        rows = plane.buffer_size // plane.line_size
        padded = np.zeros((rows, stride), dtype=data.dtype)
        padded[:data.shape[0], :data.shape[1]] = data
        plane.update(padded.astype(data.dtype.newbyteorder("<")).tobytes())
    return frame


def renumbered_truth(truth: Path, keep, out: Path) -> Path:
    """A copy of a synth truth folder whose per-frame entries follow the kept frames' new numbers."""
    out.mkdir(parents=True, exist_ok=True)
    for f in truth.iterdir():
        if f.name != "meta.json" and not (out / f.name).exists():
            (out / f.name).symlink_to(f.resolve())
    meta = json.loads((truth / "meta.json").read_text())
    new = {int(k): i for i, k in enumerate(keep)}
    meta["flash_frames"] = [new[f] for f in meta["flash_frames"] if f in new]
    meta["head_motion"] = [meta["head_motion"][int(k)] for k in keep]
    meta["light_dirs"] = {str(new[int(f)]): d for f, d in meta["light_dirs"].items() if int(f) in new}
    (out / "meta.json").write_text(json.dumps(meta))
    return out


__all__ = ["encode_like_phone", "linear_to_codes", "renumbered_truth"]
