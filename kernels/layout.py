"""The bundle format's array layout: how many texel slots a pixel's maps take.

Part of the bundle's format (:mod:`relight.kernels.bundle_format`). It sits in this leaf module
only because the maths that fills the arrays (:mod:`relight.kernels.maps`,
:mod:`relight.kernels.interpolation`) runs below the bundle: the bundle makes a recipe bundle's
maps through them, so they cannot import it.
"""

from __future__ import annotations

#: Stored texel counts are padded to a multiple of this (the relighting kernels read 16 at once).
TEXEL_ALIGN = 16


def padded_texels(n: int) -> int:
    """``n`` rounded up to a multiple of TEXEL_ALIGN (at least TEXEL_ALIGN)."""
    n = int(n)
    if n < 0:
        raise ValueError(f"texel count {n} is negative")
    return max((n + TEXEL_ALIGN - 1) // TEXEL_ALIGN * TEXEL_ALIGN, TEXEL_ALIGN)
