"""The maps' texel padding: how many texel slots a pixel's maps take (a multiple of 16, what the
relighting kernels read at once).

One rule for every array of maps: the bundle's (checked by :mod:`relight.kernels.bundle_format`,
read by :mod:`relight.kernels.bundle`), the maps kernel's output (:mod:`relight.kernels.maps`,
:mod:`relight.kernels.interpolation`), the transport's ranks (:mod:`relight.kernels.transport`)
and the relighter's operands. It sits in this leaf module because the maths that fills the
arrays runs below the bundle: the bundle makes a recipe bundle's maps through it, so it cannot
import the bundle's modules.
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
