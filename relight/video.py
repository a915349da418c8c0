"""Video in and out through PyAV (FFmpeg): the names other code imports, from the modules that
own them (one job each).

- :mod:`relight.video_read`: a file opened and validated (:func:`probe_video`), decoded -
  bounded and checked - as sRGB frames, PyAV frames or luma; decoded frames freed as they go.
- :mod:`relight.video_frame`: one decoded frame's pixels as displayed: whole (:func:`frame_to_rgb`)
  or a region kept in its native planes (:func:`crop_frame` -> :class:`FrameCrop`).
- :mod:`relight.video_orient`: the display orientation (rotation, mirror) a container gives.
- :mod:`relight.video_write`: encoding (:func:`to_yuv`, the output's colour tags) and
  :class:`VideoWriter` (H.264 + optional AAC, atomic, encoding on its own thread).
- :mod:`relight.video_colour` (a stream's colour tags -> linear Rec.709) and
  :mod:`relight.video_yuv` (a frame kept in its Y'CbCr planes) are imported from themselves.

Frames cross this boundary as (H, W, 3) uint8 sRGB arrays; convert with
:func:`relight.colour.decode_srgb8` / :func:`relight.colour.encode_srgb8`.
Writes are atomic (temporary file + rename); reads are bounded and validated.
"""

from __future__ import annotations

from .video_frame import FrameCrop as FrameCrop
from .video_frame import crop_frame as crop_frame
from .video_frame import frame_to_rgb as frame_to_rgb
from .video_frame import sws_flags as sws_flags
from .video_frame import whole_frame as whole_frame
from .video_orient import display_orientation as display_orientation
from .video_orient import orient as orient
from .video_read import MAX_VIDEO_DIM as MAX_VIDEO_DIM
from .video_read import MAX_VIDEO_FRAMES as MAX_VIDEO_FRAMES
from .video_read import METADATA_ERRORS as METADATA_ERRORS
from .video_read import RELEASE_BYTES as RELEASE_BYTES
from .video_read import VideoInfo as VideoInfo
from .video_read import probe_video as probe_video
from .video_read import read_frames as read_frames
from .video_read import read_frames_raw as read_frames_raw
from .video_read import read_luma as read_luma
from .video_read import release_frames as release_frames
from .video_write import AUDIO_BIT_RATE as AUDIO_BIT_RATE
from .video_write import AUDIO_RATE as AUDIO_RATE
from .video_write import DEFAULT_CRF as DEFAULT_CRF
from .video_write import MAX_AUDIO_SAMPLES as MAX_AUDIO_SAMPLES
from .video_write import VideoWriter as VideoWriter
from .video_write import to_yuv as to_yuv
