"""The loaded reflectance bundle - one file with everything the online side needs - as a
:class:`Bundle` (``meta`` and the memory-mapped arrays, with views the relighter and the frame
path read, and a recipe bundle's maps made again). The file format, its fields and its reader:
:mod:`relight.kernels.bundle_format`; the capture writes it (stage 6):
:mod:`relight.pipeline.bundle_write`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from relight.directions import equirect_solid_angles
from relight.errors import InputError

from .bundle_format import (
    MAPS_ONLY,
    RECIPE,
    Field,
    decode_background,
    read_bundle_file,
)
from .layout import padded_texels

#: Maps made from a recipe bundle for all its pixels are kept by the Bundle up to this size.
KEEP_MADE_MAPS_BYTES = 512 << 20
#: The ambient frame counts as a picture of the face under the room's light (:attr:`Bundle.room_light`)
#: when its median over the face is at least this share of the reference frame's.
ROOM_LIGHT_MIN_SHARE = 0.25


@dataclass
class Bundle:
    """A loaded reflectance bundle: ``meta`` (dict) and the arrays (read-only, memory-mapped).

    The fields: :mod:`relight.kernels.bundle_format`; each is also an attribute (``bundle.maps``).
    """

    path: Path | None
    meta: dict
    arrays: dict = field(repr=False)

    def __getattr__(self, name):
        arrays = self.__dict__.get("arrays", {})
        if name in arrays:
            return arrays[name]
        raise AttributeError(name)

    @property
    def frame_size(self) -> tuple[int, int]:
        """(W, H) of the reference frame."""
        w, h = self.meta["frame_size"]
        return int(w), int(h)

    @property
    def crop_origin(self) -> tuple[int, int]:
        x, y = self.meta["crop_origin"]
        return int(x), int(y)

    @property
    def map_size(self) -> tuple[int, int]:
        w, h = self.meta["map_size"]
        return int(w), int(h)

    @cached_property
    def frame_index(self) -> np.ndarray:
        """(P,) int32: each head pixel's flat index in the reference frame (row-major; the
        ``pixels`` field indexes the stored crop). Computed once, read-only."""
        w = self.frame_size[0]
        x0, y0 = self.crop_origin
        cw = np.asarray(self.arrays[Field.MASK_CROP]).shape[1]
        pix = np.asarray(self.arrays[Field.PIXELS], dtype=np.int64)
        index = ((pix // cw + y0) * w + (pix % cw + x0)).astype(np.int32)
        index.flags.writeable = False
        return index

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: the relit (head) pixels in the reference frame."""
        w, h = self.frame_size
        out = np.zeros((h, w), dtype=bool)
        x, y = self.crop_origin
        m = np.asarray(self.arrays[Field.MASK_CROP])
        out[y:y + m.shape[0], x:x + m.shape[1]] = m
        return out

    @property
    def solid_angle(self) -> np.ndarray:
        """(T,) solid angle (sr) of each stored map texel."""
        w, h = self.map_size
        rows = np.asarray(self.arrays[Field.MAP_TEXELS]) // w
        return equirect_solid_angles(w, h)[rows]

    @property
    def texel_dirs(self) -> np.ndarray:
        """(T, 3) directions of the stored map texels."""
        from relight.directions import equirect_directions

        w, h = self.map_size
        return equirect_directions(w, h).reshape(-1, 3)[np.asarray(self.arrays[Field.MAP_TEXELS])]

    def ambient_frame(self) -> np.ndarray:
        """(H, W, 3) float32 linear: the room light (``ambient``) placed in the reference frame,
        zero outside the crop: what a photo under a light adds to ``relight_light``'s image."""
        w, h = self.frame_size
        out = np.zeros((h, w, 3), dtype=np.float32)
        x, y = self.crop_origin
        a = np.asarray(self.arrays[Field.AMBIENT], dtype=np.float32)
        out[y:y + a.shape[0], x:x + a.shape[1]] = a
        return out

    @property
    def room_light(self) -> np.ndarray | None:
        """The ambient crop (h, w, 3) when it is a usable picture of the face under the capture
        room's light (its median luminance over the face at least ``ROOM_LIGHT_MIN_SHARE`` of the
        reference frame's), else None: a dark room's or an image set's near-black ambient frame is
        noise, not a reference to track or take lighting ratios against."""
        from relight.colour import decode_srgb8, luminance

        a = np.asarray(self.arrays[Field.AMBIENT], dtype=np.float32)
        m = np.asarray(self.arrays[Field.MASK_CROP], dtype=bool)
        if not m.any():
            return None
        x, y = self.crop_origin
        bg = decode_srgb8(self.background[y:y + m.shape[0], x:x + m.shape[1]])
        amb = float(np.median(luminance(a[m])))
        ref = float(np.median(luminance(bg[m])))
        return a if amb > 0.0 and amb >= ROOM_LIGHT_MIN_SHARE * ref else None

    @property
    def background(self) -> np.ndarray:
        """(H, W, 3) uint8 sRGB reference frame (decoded once from the stored JPEG)."""
        if Field.BACKGROUND in self.arrays:
            return self.arrays[Field.BACKGROUND]
        cached = self.__dict__.get("_background")
        if cached is None:
            cached = decode_background(np.asarray(self.arrays[Field.BACKGROUND_JPEG]), self.frame_size)
            cached.flags.writeable = False
            self.__dict__["_background"] = cached
        return cached

    @property
    def n_pixels(self) -> int:
        return int(self.arrays[Field.PIXELS].shape[0])

    @property
    def recipe_stored(self) -> bool:
        """Whether the bundle stores its maps' recipe (every default bundle; with --keep-maps also the maps)."""
        return all(k in self.arrays for k in RECIPE)

    @property
    def has_maps(self) -> bool:
        """Whether the bundle stores its maps (else their recipe)."""
        return Field.MAPS_ROWS in self.arrays

    @property
    def recipe(self):
        """The maps' :class:`relight.kernels.recipe.Recipe` (None for a bundle that stores its maps)."""
        if self.has_maps:
            return None
        cached = self.__dict__.get("_recipe")
        if cached is not None:
            return cached
        from .recipe import Recipe, recipe_from_arrays

        r: Recipe = recipe_from_arrays(self.arrays, self.meta, self.map_size)
        self.__dict__["_recipe"] = r
        return r

    def default(self) -> Bundle:
        """The bundle as ``relight capture`` writes it without ``--keep-maps``: this one without
        its stored maps (its recipe then makes them). Raises InputError for a bundle with no recipe."""
        missing = [k for k in RECIPE if k not in self.arrays]
        if missing:
            raise InputError(f"{self.path}: no recipe stored (missing {', '.join(missing)}); the maps are all it has")
        arrays = {k: v for k, v in self.arrays.items() if k not in MAPS_ONLY}
        return Bundle(path=self.path, meta=self.meta, arrays=arrays)

    @property
    def default_nbytes(self) -> int:
        """Bytes of the arrays :meth:`default` keeps (its file size but for the header and alignment)."""
        return int(sum(a.nbytes for k, a in self.arrays.items() if k not in MAPS_ONLY))

    def texel_rows(self, index) -> np.ndarray:
        """(n, 3, P) float16 maps of the stored texels ``index`` (positions in ``map_texels``)
        for every head pixel: read from ``maps_rows``, or made from the recipe."""
        idx = np.asarray(index, dtype=np.int64).ravel()
        if self.has_maps:
            return np.asarray(self.arrays[Field.MAPS_ROWS][idx])
        from .recipe import texel_rows

        tex = np.asarray(self.arrays[Field.MAP_TEXELS], dtype=np.int64)[idx]
        return _to_half(texel_rows(self.recipe, tex))

    def pixel_maps(self, index=None, *, padded: bool = True) -> np.ndarray:
        """(n, 3, Tp) float16 pixel-major maps of the head pixels ``index`` (an index array or
        slice into ``pixels``; None: all), zero padded to Tp texels (a multiple of 16) unless
        ``padded`` is False. From ``maps`` when the bundle stores it, else gathered from
        ``maps_rows`` (memory: the result only)."""
        if Field.MAPS in self.arrays:
            sel = self.arrays[Field.MAPS] if index is None else self.arrays[Field.MAPS][index]
            out = np.asarray(sel)
            return out if padded else out[:, :, :self.arrays[Field.MAP_TEXELS].shape[0]]
        if not self.has_maps:
            from .recipe import recipe_maps

            r = self.recipe
            if index is None:
                # Made once per loaded bundle while small enough to keep (exact relighters, the
                # accuracy bench); larger ones are made again on each call.
                out = self.__dict__.get("_made_maps")
                if out is None:
                    out = recipe_maps(r, half=True)
                    if out.nbytes <= KEEP_MADE_MAPS_BYTES:
                        out.flags.writeable = False
                        self.__dict__["_made_maps"] = out
            else:
                out = recipe_maps(r.subset(np.arange(self.n_pixels)[index]), half=True)
            return out if padded else out[:, :, :self.arrays[Field.MAP_TEXELS].shape[0]]
        rows = self.arrays[Field.MAPS_ROWS]
        t = rows.shape[0]
        idx = np.arange(rows.shape[2]) if index is None else np.arange(rows.shape[2])[index]
        out = np.zeros((idx.size, 3, padded_texels(t) if padded else t), dtype=np.float16)
        step = 8192
        for i0 in range(0, idx.size, step):
            part = idx[i0:i0 + step]
            if part.size and part[-1] - part[0] + 1 == part.size and np.all(np.diff(part) == 1):
                blk = np.asarray(rows[:, :, part[0]:part[-1] + 1])  # a run: one strided read
            else:
                blk = np.asarray(rows[:, :, part])
            out[i0:i0 + part.size, :, :t] = blk.transpose(2, 1, 0)
        return out

    def full_map(self, pixel: int) -> np.ndarray:
        """(H_map, W_map, 3) float32 reflectance map of one head pixel (index into ``pixels``)."""
        w, h = self.map_size
        tex = np.asarray(self.arrays[Field.MAP_TEXELS])
        out = np.zeros((h * w, 3), dtype=np.float32)
        out[tex] = self.pixel_maps(np.array([int(pixel)]), padded=False)[0].T
        return out.reshape(h, w, 3)


def _to_half(a: np.ndarray) -> np.ndarray:
    """float16 of non-negative maps, halves below the normal range flushed to 0 (as the kernels read them)."""
    from relight.numerics import flush_subnormal_halves

    return flush_subnormal_halves(a.astype(np.float16))


def load_bundle(path: str | os.PathLike, *, verify: bool = True) -> Bundle:
    """Open a bundle: header validated, every array checked (CRC-32) and memory-mapped read-only
    (:func:`relight.kernels.bundle_format.read_bundle_file`).

    Raises :class:`InputError` naming the problem and the field for a missing, truncated,
    corrupted, foreign or wrong-version file.
    """
    meta, arrays = read_bundle_file(path, verify=verify)
    return Bundle(path=Path(path), meta=meta, arrays=arrays)
