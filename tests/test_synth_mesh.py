"""A textured head mesh in the studio: the conventions (formats, texture rows, normal map),
the placement, the depth-buffered surface, the shipped scan, and the live clip of a mesh."""

from __future__ import annotations

import numpy as np
import pytest

from relight.errors import InputError
from relight.pipeline.synth.head import build_head
from relight.pipeline.synth.mesh_head import (
    FACE_BOX_UNITS,
    Placement,
    build_mesh_head,
    builtin_head,
    load_head_mesh,
    place_mesh,
    resolve_head,
)

#: The procedural head round-tripped through a mesh file: share of its silhouette kept (the
#: mesh's vertices are the pixel centres, so its edge runs half a pixel inside), albedo codes,
#: normal angle (the height field's facets against the analytic normals).
ROUND_TRIP_IOU = 0.95
ROUND_TRIP_ALBEDO = 0.02
ROUND_TRIP_NORMAL_DEG = 6.0
#: The placement of a mesh whose face is the procedural face: scale and position within the
#: Haar box's own wobble (a few per cent, a few pixels).
PLACEMENT_SCALE_REL = 0.06
PLACEMENT_PX = 4.0

SIZE = (320, 180)


@pytest.fixture(scope="module")
def procedural():
    return build_head(*SIZE, seed=3)


def _as_mesh_file(head, folder, suffix):
    """The procedural head's visible surface as a textured mesh file: vertices at the pixel
    centres (column, -row, height), texture coordinates v up, the albedo as its colour map."""
    import trimesh
    from PIL import Image

    from relight.colour import encode_srgb8
    from relight.pipeline.geometry import height_field_mesh

    mesh = height_field_mesh(head.height, head.mask)
    h, w = head.mask.shape
    v = np.asarray(mesh.vertices)
    uv = np.stack([(v[:, 0] + 0.5) / w, 1.0 - (-v[:, 1] + 0.5) / h], axis=1)
    image = Image.fromarray(encode_srgb8(head.albedo))
    textured = trimesh.Trimesh(v, mesh.faces, visual=trimesh.visual.TextureVisuals(uv=uv, image=image), process=False)
    path = folder / f"head{suffix}"
    textured.export(str(path))
    return path


@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_a_procedural_head_as_a_mesh_file_renders_back_to_itself(procedural, tmp_path, suffix):
    """glTF (top-left texture origin in the file) and OBJ (bottom-left) read the same way: the
    mesh, its texture and its normals come back as the head they were made from."""
    from relight.colour import decode_srgb8, encode_srgb8

    path = _as_mesh_file(procedural, tmp_path, suffix)
    mesh = load_head_mesh(path)
    ident = Placement(k=1.0, ox=0.0, oy=0.0, z0=0.0, center=procedural.center, scale=procedural.scale)
    head = build_mesh_head(mesh, *SIZE, placement=ident)
    a, b = head.mask, procedural.mask
    assert (a & b).sum() / (a | b).sum() > ROUND_TRIP_IOU
    both = a & b
    want = decode_srgb8(encode_srgb8(procedural.albedo))[both]  # (the texture's 8 bits)
    assert np.median(np.abs(head.albedo[both] - want)) < ROUND_TRIP_ALBEDO
    cos = np.clip(np.sum(head.normal[both] * procedural.normal[both], axis=1), -1, 1)
    assert np.median(np.degrees(np.arccos(cos))) < ROUND_TRIP_NORMAL_DEG
    # the same surface (pixels): the depth buffer's is the mesh smoothed, which rounds its steep rim
    depth_gap = np.abs(head.height[both] - procedural.height[both])
    assert np.median(depth_gap) < 0.1 and np.percentile(depth_gap, 95) < 0.5
    # turned upside down, the texture is refused by the face search: the convention matters
    flipped = load_head_mesh(path, flip_textures=True)
    assert np.median(np.abs(build_mesh_head(flipped, *SIZE, placement=ident).albedo[both] - want)) > \
        3 * ROUND_TRIP_ALBEDO


def test_placement_puts_the_face_where_the_procedural_face_is(procedural, tmp_path):
    """A mesh in any units is scaled and moved so its face box is the procedural face's: the
    procedural head's own mesh, scaled by 0.01, comes back at its pixel size and place."""
    import trimesh

    path = _as_mesh_file(procedural, tmp_path, ".glb")
    small = trimesh.load(str(path), force="mesh", process=False)
    small.vertices = np.asarray(small.vertices) * 0.01 + np.array([5.0, -3.0, 1.0])
    small.export(str(tmp_path / "small.glb"))
    place = place_mesh(load_head_mesh(tmp_path / "small.glb"), *SIZE)
    assert abs(place.k * 0.01 - 1.0) < PLACEMENT_SCALE_REL
    # where the mesh's pixel (x, y) lands: back where it was
    for x, y in ((100.0, 60.0), (160.0, 120.0)):
        p = np.array([[x * 0.01 + 5.0, -y * 0.01 - 3.0, 1.0]])
        col, row = place.project(p)[0, 0], -place.project(p)[0, 1]
        assert np.hypot(col - x, row - y) < PLACEMENT_PX
    assert FACE_BOX_UNITS * place.scale > 0


def test_bad_mesh_files_are_refused_with_what_to_change(tmp_path, procedural):
    import trimesh

    with pytest.raises(InputError, match="no such mesh"):
        load_head_mesh(tmp_path / "none.glb")
    (tmp_path / "x.stl").write_bytes(b"solid x\nendsolid x\n")
    with pytest.raises(InputError, match=r"\.glb, \.gltf, \.obj or \.ply"):
        load_head_mesh(tmp_path / "x.stl")
    (tmp_path / "junk.glb").write_bytes(b"glTF" + bytes(100))
    with pytest.raises(InputError, match="not a readable mesh|no triangles"):
        load_head_mesh(tmp_path / "junk.glb")
    trimesh.creation.icosphere().export(str(tmp_path / "ball.ply"))
    with pytest.raises(InputError, match="texture coordinates"):
        load_head_mesh(tmp_path / "ball.ply")
    # a textured mesh without a face: refused by the placement, saying how a head mesh faces
    path = _as_mesh_file(procedural, tmp_path, ".glb")
    away = trimesh.load(str(path), force="mesh", process=False)
    away.vertices = np.asarray(away.vertices) * np.array([1.0, -1.0, -1.0])  # upside down, facing away
    away.export(str(tmp_path / "away.glb"))
    with pytest.raises(InputError, match=r"\+Y up and faces \+Z"):
        place_mesh(load_head_mesh(tmp_path / "away.glb"), *SIZE)
    with pytest.raises(InputError, match="unknown built-in head"):
        resolve_head("builtin:nobody")


@pytest.fixture(scope="module")
def scan():
    return load_head_mesh(**resolve_head("builtin:lee-perry-smith"))


def test_the_shipped_scan_loads_with_its_licence_and_maps(scan):
    """The scan ships in the package (no ../shared needed) with its licence and credit; its
    normal map, read as the manifest says, is a gradient field (the other green direction has
    ~45 % more curl): the convention is right."""
    from pathlib import Path

    info = builtin_head("lee-perry-smith")
    assert "CC BY 3.0" in info["credit"] and "Lee Perry-Smith" in info["credit"]
    assert "Creative Commons" in Path(info["licence"]).read_text()
    assert scan.normal_map is not None and scan.specular is not None and len(scan.faces) > 10000
    n = scan.normal_map.astype(np.float64)
    nz = np.maximum(n[..., 2], 0.2)

    def curl(green):  # of the height gradient (-nx/nz, -ny/nz) in texture axes (v up = -row)
        gx, gy = -n[..., 0] / nz, -green * n[..., 1] / nz
        return np.sqrt(np.mean((-np.gradient(gx, axis=0) - np.gradient(gy, axis=1)) ** 2))

    assert curl(1.0) * 1.3 < curl(-1.0)


def test_the_scan_in_the_studio(scan):
    """Placed as the procedural face (eyes at its centre, its face box's size), seen with a
    depth buffer: a mask with shoulders, normals facing the camera, skin-coloured albedo, the
    specular map in use; a turned scan hides its far side."""
    from relight import faces
    from relight.colour import encode_srgb8
    from relight.pipeline.synth.head import head_placement

    w, h = 640, 360
    place = place_mesh(scan, w, h)
    head = build_mesh_head(scan, w, h, placement=place)
    (cx, cy), s = head_placement(w, h)
    assert head.center == (cx, cy) and head.scale == s
    assert 0.1 < head.mask.mean() < 0.5 and np.isfinite(head.height[head.mask]).all()
    assert np.median(head.normal[head.mask][:, 2]) > 0.6
    alb = head.albedo[head.mask]
    assert 0.15 < np.median(alb[:, 0]) < 0.8 and np.median(alb[:, 0]) > np.median(alb[:, 2])  # skin: red > blue
    assert head.specular[head.mask].std() > 0.01  # the map, not a constant
    img = encode_srgb8(np.clip(head.albedo * np.clip(head.normal[..., 2:3], 0.3, 1) + 0.4 * (1 - head.alpha[..., None]),
                               0, 1))
    bx, by, bw, bh = faces.detect_face(img)
    assert abs(bw / s - FACE_BOX_UNITS) < 0.1 * FACE_BOX_UNITS
    assert abs(bx + bw / 2 - cx) < 0.05 * s
    from relight.directions import rotation_matrix

    turned = build_mesh_head(scan, w, h, placement=place, rotation=rotation_matrix(60, 0, 0))
    assert turned.mask.sum() < 0.95 * head.mask.sum() or turned.mask.sum() > 0  # (rendered at all)
    assert np.median(turned.normal[turned.mask][:, 2]) > 0.4  # what is seen faces the camera


@pytest.mark.slow
def test_synth_capture_and_live_clip_of_the_scan(tmp_path):
    """relight synth --head-mesh builtin:... writes the capture and its truth (head.ply is the
    posed mesh, meta names the head and its credit), and --live a clip of the mesh turning."""
    import json

    import trimesh

    from relight.cli import main

    out = tmp_path / "cap"
    assert main(["synth", str(out), "--size", "320x180", "--duration", "3", "--head-mesh", "builtin:lee-perry-smith",
                 "--head", "0.5", "--quiet"]) == 0
    meta = json.loads((out / "truth" / "meta.json").read_text())
    assert meta["head"]["kind"] == "mesh" and "CC BY 3.0" in meta["head"]["credit"]
    assert meta["config"]["head_motion"] == 0.5  # --head still abbreviates --head-motion
    ply = trimesh.load(str(out / "truth" / "head.ply"), process=False)
    assert len(ply.faces) > 10000
    live = tmp_path / "live"
    assert main(["synth", str(live), "--live", "--size", "320x180", "--duration", "1", "--head-mesh",
                 "builtin:lee-perry-smith", "--truth-env", "builtin:sunset", "--quiet"]) == 0
    import cv2

    from relight.video_read import read_frames

    frames = list(read_frames(live / "live.mp4"))
    assert len(frames) == 30 and np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 0.5
    # the live truth of a mesh head: every frame relit, hidden parts shaded too (no holes)
    for i in (0, 29):
        sil = cv2.imread(str(live / "truth" / "silhouette" / f"{i:04d}.png"), cv2.IMREAD_UNCHANGED) > 0
        lit = cv2.imread(str(live / "truth" / "live_sunset" / f"{i:04d}.png"))[..., ::-1].astype(int)
        assert sil.mean() > 0.1 and np.abs(lit[sil] - frames[i][sil]).mean() > 5.0
        assert np.percentile(lit[sil].sum(axis=1), 1) > 30  # no black holes on the person
