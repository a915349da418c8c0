"""The light directions' triangulation as the maps read it (paper section 3.2, step 1):
:class:`Triangulation` - the sample directions and the virtual black lights, the spherical
Delaunay faces, each map texel's triangle with its spherical barycentric weights, the texels
touching a sample - and the map geometry derived from it (texel directions, solid angles, each
vertex's texel). The capture makes it (:func:`relight.pipeline.triangulate.triangulate`); a
bundle stores it and its recipe rebuilds it (:mod:`relight.kernels.recipe`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.directions import direction_to_equirect_uv, equirect_directions, equirect_solid_angles


@dataclass
class Triangulation:
    """Sample directions, virtual black lights, the hull and each texel's triangle.

    vertices : (K + B, 3) unit directions, the K samples first. faces : (F, 3) vertex ids.
    texel_vertices : (T, 3) the vertices of each texel's triangle; texel_weights : (T, 3) its
    spherical barycentric weights (sum 1). active : (T,) texels touching a sample (the others
    are black). map_size : (width, height).
    """

    vertices: np.ndarray
    n_samples: int
    faces: np.ndarray
    texel_vertices: np.ndarray
    texel_weights: np.ndarray
    active: np.ndarray
    map_size: tuple[int, int]

    @property
    def texel_dirs(self) -> np.ndarray:
        w, h = self.map_size
        return equirect_directions(w, h).reshape(-1, 3)

    @property
    def vertex_texel(self) -> np.ndarray:
        """(V,) the map texel holding each vertex direction (where its visibility is read)."""
        w, h = self.map_size
        u, v = direction_to_equirect_uv(self.vertices)
        return (np.minimum((v * h).astype(np.int64), h - 1) * w + np.minimum((u * w).astype(np.int64), w - 1))

    @property
    def solid_angle(self) -> np.ndarray:
        """(T,) exact solid angle of each texel (sr)."""
        w, h = self.map_size
        return np.repeat(equirect_solid_angles(w, h), w)
