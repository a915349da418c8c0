"""Any picture as the light: ``photo:beach.jpg`` - a photo of a place, a virtual background, a
phone picture - made into a plausible lat-long environment (:func:`photo_environment`).

What it assumes, since a photo holds a small part of the sphere and no radiance above white:

* **Where the photo is**: it is what lies behind the person as the camera sees them, spread over
  :data:`PHOTO_FOV_DEG` degrees of azimuth around -Z (away from the camera) - its left on the
  image's left (-X), its top up (+Y), by angle (azimuth and elevation linear in the photo's
  columns and rows); beyond its edges the edge's colours go on (the sky above its top row, the
  ground below its bottom row, its sides around to the sides of the person).
* **What lights the face**: the same scene mirrored toward the person (the hemisphere in front,
  toward the camera: a direction (x, y, z) sees what (x, y, -z) behind shows), blurred by
  :data:`FRONT_BLUR_DEG` - light from the scene's bright side reaches the face from that side; the
  hemisphere behind keeps the photo's detail (blurred by :data:`BACK_BLUR_DEG`), for rim light
  and thumbnails; the two are blended over +-:data:`SEAM_Z` in z.
* **HDR where it clips**: pixels at the top of the range (sun, lamps, windows, a bright sky) were
  brighter than white; they are expanded by up to :data:`HDR_GAIN` x, more where clipped pixels
  crowd (a blurred density of them: Banterle et al. 2006's expand map, simplified), so a window
  outshines a white shirt.
* **Exposure from its brightness**: the map is scaled so a white surface facing the camera reads
  :data:`MID_READING` flashes for a photo of mean luminance :data:`MID_GREY`, and the square root
  of the photo's mean over it otherwise (a dim room lights dimmer than a beach, by less than its
  pixels say: cameras expose both toward mid-grey), clipped to :data:`READING_RANGE`.

Photos of any size are read (within :func:`relight.imageio.read_image`'s limits), their EXIF
orientation honoured, and resized to the work size. Colours: the photo is decoded from sRGB to
linear Rec.709; the map is linear radiance in flash units, as every environment.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from .colour import LUMINANCE, linear_to_srgb
from .directions import equirect_directions, equirect_solid_angles
from .errors import InputError
from .numerics import ACCUM, EPS, FLOAT

#: The photo's horizontal field of view on the sphere (degrees): a phone's main camera sees
#: 65-80 degrees; a little more keeps the scene's sides (windows at the edges) to the sides.
PHOTO_FOV_DEG = 90.0
#: Blur of the mirrored scene that lights the face, and of the scene behind (degrees, Gaussian
#: sigma on the photo).
FRONT_BLUR_DEG = 20.0
BACK_BLUR_DEG = 1.5
#: The front and back hemispheres blend over |z| < SEAM_Z (unit direction's z).
SEAM_Z = 0.25
#: Clipped pixels: sRGB values from HDR_KNEE to 1 (largest channel) are taken as clipped, and
#: expanded by up to HDR_GAIN x (4 stops), weighted by the clipped pixels' density within
#: HDR_SPREAD_DEG degrees.
HDR_KNEE = 0.92
HDR_GAIN = 16.0
HDR_SPREAD_DEG = 3.0
#: Exposure: a photo of mean linear luminance MID_GREY makes a white surface facing the camera
#: read MID_READING flashes; others sqrt(mean / MID_GREY) times that, within READING_RANGE.
MID_GREY = 0.18
MID_READING = 0.8
READING_RANGE = (0.25, 1.6)
#: The photo is resized (area filter) to at most this many pixels on its longer side first.
WORK_SIDE = 384
#: Largest photo read: 8192 px a side, 50 MP in all (a 48 MP phone photo; ~0.6 GB while decoded
#: to float). Larger ones are refused before decoding, saying to downscale.
MAX_PHOTO_SIDE = 8192
MAX_PHOTO_PIXELS = 8192 * 6144


def expand_highlights(photo: np.ndarray, px_per_deg: float) -> np.ndarray:
    """(h, w, 3) linear photo -> the same with its clipped pixels expanded (see the module
    docstring; ``px_per_deg``: the photo's pixels per degree, for the density's spread)."""
    top = linear_to_srgb(photo.max(axis=2))
    clipped = np.clip((top - HDR_KNEE) / (1.0 - HDR_KNEE), 0.0, 1.0).astype(np.float32)
    if not clipped.any():
        return photo
    sigma = max(HDR_SPREAD_DEG * px_per_deg, 0.5)
    density = cv2.GaussianBlur(clipped, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    gain = 1.0 + (HDR_GAIN - 1.0) * clipped * np.clip(density, 0.0, 1.0)
    return photo * gain[..., None]


def photo_environment(photo: np.ndarray, width: int = 512) -> np.ndarray:
    """A (width / 2, width, 3) float32 lat-long environment of linear radiance made from ``photo``
    ((h, w, 3) linear Rec.709, upright; any size) as the module docstring says."""
    photo = np.asarray(photo, dtype=np.float32)
    if photo.ndim != 3 or photo.shape[2] != 3 or min(photo.shape[:2]) < 2:
        raise InputError(f"photo of shape {photo.shape}: expected an (H, W, 3) image of at least 2x2 pixels")
    if not np.isfinite(photo).all() or photo.min() < 0:
        raise InputError("the photo has non-finite or negative values")
    h, w = photo.shape[:2]
    s = min(1.0, WORK_SIDE / max(h, w))
    if s < 1.0:
        photo = cv2.resize(photo, (max(2, round(w * s)), max(2, round(h * s))), interpolation=cv2.INTER_AREA)
        h, w = photo.shape[:2]
    mean = float(np.mean(photo.reshape(-1, 3).astype(ACCUM) @ LUMINANCE.astype(ACCUM)))
    px_per_deg = w / PHOTO_FOV_DEG
    if float(photo.max()) <= 1.0:  # an 8- or 16-bit photo clipped at white (an HDR one is as it is)
        photo = expand_highlights(photo, px_per_deg)
    back = cv2.GaussianBlur(photo, (0, 0), max(BACK_BLUR_DEG * px_per_deg, 0.3), borderType=cv2.BORDER_REPLICATE)
    front = cv2.GaussianBlur(photo, (0, 0), FRONT_BLUR_DEG * px_per_deg, borderType=cv2.BORDER_REPLICATE)

    # Where each of the map's texels looks in the photo: azimuth from -Z (the mirror: from +Z in
    # front) and elevation, linear in the photo's columns and rows; beyond its edges, its edges.
    dirs = equirect_directions(width, width // 2)
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    az = np.degrees(np.arctan2(x, np.abs(z)))
    el = np.degrees(np.arcsin(np.clip(y, -1.0, 1.0)))
    vfov = PHOTO_FOV_DEG * h / w
    map_x = ((az / PHOTO_FOV_DEG + 0.5) * w - 0.5).astype(np.float32)
    map_y = ((0.5 - el / vfov) * h - 0.5).astype(np.float32)
    seen_back = cv2.remap(back, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    seen_front = cv2.remap(front, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    t = np.clip((z / SEAM_Z + 1.0) / 2.0, 0.0, 1.0)[..., None]  # 0 behind, 1 in front
    t = t * t * (3.0 - 2.0 * t)
    env = (seen_back * (1.0 - t) + seen_front * t).astype(ACCUM)

    # Exposure: what a white surface facing the camera reads, set from the photo's brightness.
    cos = np.clip(z, 0.0, None) * equirect_solid_angles(width, width // 2)[:, None]
    reading = float(np.einsum("hw,hwc->c", cos, env) @ LUMINANCE.astype(ACCUM)) / np.pi
    lo, hi = READING_RANGE
    want = float(np.clip(MID_READING * np.sqrt(max(mean, EPS) / MID_GREY), lo, hi))
    if reading <= EPS:  # a black photo: a dim uniform light, not a division by zero
        return np.full_like(env, lo, dtype=FLOAT)
    return (env * (want / reading)).astype(FLOAT)


def load_photo_environment(path: str | os.PathLike, *, width: int = 512) -> np.ndarray:
    """The environment of the photo at ``path`` (:func:`photo_environment`): PNG, JPEG, EXR, HDR,
    any size within the reader's limits, its EXIF orientation honoured; InputError for a missing,
    hostile or corrupt file, saying what to change."""
    from .imageio import read_image

    photo = read_image(path, orient=True, max_dim=MAX_PHOTO_SIDE, max_pixels=MAX_PHOTO_PIXELS)
    return photo_environment(photo, width)
