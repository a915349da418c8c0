"""Stage 4: photometric stereo, depth integration, meshes."""

import numpy as np
import pytest

from relight.directions import angle_between_deg
from relight.errors import InputError
from relight.pipeline.geometry import (
    head_mask,
    height_field_mesh,
    integrate_normals,
    photometric_stereo,
    rasterize_mesh,
)

from .tolerances import (
    ALBEDO_REL,
    HEAD_MASK_AGREE,
    INTEGRATION_PX,
    PS_NORMAL_MEDIAN_DEG,
    PS_NORMAL_P99_DEG,
    RASTER_NORMAL_DEG,
)


def _dome(h=80, w=100, r=34.0):
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    cx, cy = w / 2, h / 2
    r2 = ((x - cx) ** 2 + (y - cy) ** 2) / r**2
    mask = r2 < 0.81  # leave out the steep rim
    z = r * np.sqrt(np.clip(1 - r2, 0, None))
    n = np.stack([(x - cx) / r, -(y - cy) / r, z / r], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return mask, z, n


def _lights(k=40, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(k, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.4
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_photometric_stereo_recovers_normals_and_albedo():
    mask, _, n = _dome()
    dirs = _lights()
    albedo = np.array([0.6, 0.4, 0.3])
    shade = np.clip(n @ dirs.T, 0, None)  # (h, w, k)
    images = (shade.transpose(2, 0, 1)[..., None] * albedo).astype(np.float32)
    images += 0.002 * np.random.default_rng(1).standard_normal(images.shape).astype(np.float32)
    # Specular spikes and a clipped sample must not bend the fit.
    images[3, 30:40, 40:50] += 2.0
    clipped = np.zeros(images.shape[:3], dtype=bool)
    clipped[5, 20:30] = True
    nn, alb, _ = photometric_stereo(images, dirs, mask, clipped)
    ang = angle_between_deg(nn[mask], n[mask])
    assert np.median(ang) < PS_NORMAL_MEDIAN_DEG and np.percentile(ang, 99) < PS_NORMAL_P99_DEG
    np.testing.assert_allclose(np.median(alb[mask], axis=0), albedo, rtol=ALBEDO_REL)
    assert (nn[~mask] == 0).all()


def test_depth_integration_matches_the_shape():
    mask, z, n = _dome()
    depth = integrate_normals(n, mask)
    err = (depth - z)[mask]
    err -= err.mean()
    assert np.abs(err).max() < INTEGRATION_PX  # pixels, on a 34-pixel dome


def test_mesh_round_trip():
    mask, z, n = _dome()
    mesh = height_field_mesh(z, mask, origin=(10, 20))
    depth, normal, cover = rasterize_mesh(mesh, mask.shape, origin=(10, 20))
    inner = mask & np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1) & np.roll(mask, -1, 1)
    assert cover[inner].all()
    assert np.abs(depth - z)[inner].max() < 1e-4  # float32 depth
    assert np.median(angle_between_deg(normal[inner], n[inner])) < RASTER_NORMAL_DEG
    with pytest.raises(InputError):
        mesh.vertices[0, 0] = np.nan
        rasterize_mesh(mesh, mask.shape)


def test_head_mask_uses_the_flash_falloff():
    h, w = 60, 80
    ambient = np.full((h, w, 3), 0.05, dtype=np.float32)
    flash = np.full((8, h, w, 3), 0.02, dtype=np.float32)  # the wall: a little flash
    yy, xx = np.mgrid[0:h, 0:w]
    head = (xx - 40) ** 2 / 20**2 + (yy - 30) ** 2 / 25**2 < 1
    flash[:, head] = 0.4
    flash[:, 28:31, 35:38] = 0.01  # a dark pupil stays inside (holes are filled)
    mask = head_mask(flash, ambient, (30, 15, 20, 30))
    assert (mask == head).mean() > HEAD_MASK_AGREE
