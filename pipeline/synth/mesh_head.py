"""A textured head mesh in the studio (``relight synth --head-mesh FILE``): loaded, placed,
and rasterised with a depth buffer.

Conventions. The mesh is +Y up and faces +Z (toward the camera), any unit; the studio's camera
is orthographic, looking along -Z. Texture coordinates follow trimesh's (OpenGL's, OBJ's):
``v`` counts up from the image's bottom row, so texel row = ``(1 - v) * (rows - 1)`` - trimesh
turns glTF's top-left origin into this on load. Some assets pair glTF coordinates with images
stored the other way up (three.js's LeePerrySmith example: its external JPEGs are read with
``flipY``); ``flip_textures`` turns such images the right way once, on load.

Placement. A front view of the mesh (its colour map under a frontal light) is searched with the
same Haar cascade the capture uses, and the mesh is scaled and moved so that this face box has
the procedural head's size and place at the frame size (:data:`FACE_BOX_UNITS`,
:data:`FACE_BOX_CENTER`): the face spans what the procedural face spans, whatever the mesh's
units and whatever else it holds (neck, shoulders). The eyes' level is then the procedural
head's ``center``. A mesh with no face in its front view is refused.

Surface. At a pose the mesh is rasterised at the pixel centres with a depth buffer (the nearest
surface wins: a turned head hides parts of itself) and at 4x4 samples a pixel for the
silhouette's coverage. Each visible pixel takes the barycentric blend of its triangle's vertex
normals (bent by a tangent-space normal map when given: OpenGL's convention, green toward +v),
its texture coordinates, and from them the colour map (used as the diffuse albedo, linear light:
it has some shading baked in, which the truth then holds as albedo - the truth is what the
renderer draws) and the specular map. Normals at the silhouette are kept within the procedural
head's steepest slope (:data:`.head.MAX_SLOPE`): what a height field's shading and the capture's
photometric stereo can represent.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relight.errors import InputError
from relight.numerics import EPS_NORM, EPS_VALUE, FLOAT

from .head import ALPHA_SUPERSAMPLE, MAX_SLOPE, Head, head_placement

#: Limits of what a head mesh may hold (a scan of a head has ~1e4-1e6 triangles).
MAX_MESH_FACES = 4_000_000
MAX_MESH_BYTES = 512 << 20
MAX_TEXTURE_SIDE = 8192
#: The procedural head's face, as the Haar cascade boxes it: width in head units (``Head.scale``
#: pixels each) and the box centre relative to ``Head.center`` (head units, +v up). Measured on
#: the procedural head at 480x270, 640x360 and 960x540: 1.420-1.432 and (0.00, -0.063..-0.075).
FACE_BOX_UNITS = 1.425
FACE_BOX_CENTER = (0.0, -0.07)
#: Pixels across the face in the front view the placement searches.
PLACEMENT_FACE_PX = 240
#: Loop subdivisions of the depth buffer's surface (each: 4x the triangles), unless that passes
#: MAX_SMOOTH_FACES (a dense scan's facets are already below a pixel).
SMOOTH_ITERATIONS = 2
MAX_SMOOTH_FACES = 2_000_000
#: Skin parameters where the mesh has no map for them (the procedural head's skin).
SKIN_SPECULAR = 0.35
SKIN_ROUGHNESS = 0.38
SKIN_WRAP = (0.30, 0.14, 0.09)
#: Specular weight of a white texel of a specular map (the procedural head's oily T-zone: 0.6).
SPECULAR_MAP_MAX = 0.6


@dataclass(frozen=True)
class HeadMesh:
    """A head mesh ready to rasterise (see the module docstring for the conventions).

    vertices : (V, 3) float64 mesh units, +Y up, +Z toward the camera. faces : (T, 3) int64.
    uv : (V, 2) float64 texture coordinates, v up. normals : (V, 3) unit vertex normals.
    tangents, bitangents : (V, 3) unit tangent frame (+u, +v directions on the surface).
    smooth_vertices, smooth_faces : the surface :data:`SMOOTH_ITERATIONS` Loop subdivisions
    smoother - the depth buffer's, so shadows follow the surface and not its facets (a low-poly
    mesh's flat triangles under smooth normals cut a shadow's edge into steps).
    albedo : (h, w, 3) float32 linear colour map. specular : (h, w) float32 0-1 or None.
    normal_map : (h, w, 3) float32 tangent-space normals (-1..1) or None. source : the file.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    bitangents: np.ndarray
    albedo: np.ndarray
    specular: np.ndarray | None
    normal_map: np.ndarray | None
    source: str
    smooth_vertices: np.ndarray | None = None
    smooth_faces: np.ndarray | None = None


def _read_map(path, what: str, *, colour: bool, flip: bool) -> np.ndarray:
    from relight.imageio import read_image

    img = read_image(path, linearize=colour, max_dim=MAX_TEXTURE_SIDE)
    if img.ndim == 2:
        img = img[..., None]
    if not np.isfinite(img).all():
        raise InputError(f"{path}: the {what} holds non-finite values")
    img = np.ascontiguousarray(img[::-1] if flip else img, dtype=FLOAT)
    return img


#: Heads shipped with relight: ``builtin:NAME`` for ``--head-mesh`` (the package's
#: ``pipeline/synth/heads/NAME/head.json``: its files, credit, licence and what was changed).
BUILTIN_HEADS = ("lee-perry-smith",)
#: The head the demo shows.
DEMO_HEAD = "builtin:lee-perry-smith"


def builtin_head(name: str) -> dict:
    """The manifest of a shipped head (``head.json``) with its files as absolute paths."""
    import json
    from importlib.resources import files

    if name not in BUILTIN_HEADS:
        raise InputError(f"unknown built-in head {name!r}; choose one of: "
                         + ", ".join(f"builtin:{n}" for n in BUILTIN_HEADS))
    folder = files("relight.pipeline.synth").joinpath("heads", name)
    info = json.loads(folder.joinpath("head.json").read_text(encoding="utf-8"))
    for key in ("mesh", "texture", "specular_map", "normal_map", "licence"):
        if info.get(key):
            info[key] = str(folder.joinpath(info[key]))
    return info


def resolve_head(mesh: str, *, texture=None, normal_map=None, specular_map=None, flip_textures: bool = False) -> dict:
    """``load_head_mesh``'s arguments for ``--head-mesh`` (a file, or ``builtin:NAME``: its
    manifest's files unless given)."""
    if not str(mesh).startswith("builtin:"):
        return {"path": mesh, "texture": texture, "normal_map": normal_map, "specular_map": specular_map,
                "flip_textures": flip_textures}
    info = builtin_head(str(mesh)[len("builtin:"):])
    return {"path": info["mesh"], "texture": texture or info.get("texture"),
            "normal_map": normal_map or info.get("normal_map"),
            "specular_map": specular_map or info.get("specular_map"),
            "flip_textures": bool(info.get("flip", False)) if texture is None else flip_textures}


def head_credit(mesh: str | None) -> str | None:
    """The credit line a picture of this head must carry (a shipped head's), else None."""
    if mesh is None or not str(mesh).startswith("builtin:"):
        return None
    return builtin_head(str(mesh)[len("builtin:"):]).get("credit")


def load_head_mesh(path, *, texture=None, normal_map=None, specular_map=None,
                   flip_textures: bool = False) -> HeadMesh:
    """Load a head mesh (``.glb``/``.gltf``/``.obj``/``.ply``, through trimesh) with its colour
    map - embedded, or ``texture`` - and optionally a tangent-space ``normal_map`` and a
    grey ``specular_map``. Raises :class:`InputError` for what cannot be used, saying what to change."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such mesh file; check the path")
    if path.suffix.lower() not in (".glb", ".gltf", ".obj", ".ply"):
        raise InputError(f"{path}: a head mesh is .glb, .gltf, .obj or .ply")
    if path.stat().st_size > MAX_MESH_BYTES:
        raise InputError(f"{path}: {path.stat().st_size / 1e6:.0f} MB is more than a head mesh needs "
                         f"(at most {MAX_MESH_BYTES >> 20} MB); decimate it")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - trimesh's parsers raise many kinds
        raise InputError(f"{path}: not a readable mesh ({type(exc).__name__}: {exc})") from exc
    v = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    if v.ndim != 2 or v.shape[1:] != (3,) or f.ndim != 2 or f.shape[1:] != (3,) or not len(v) or not len(f):
        raise InputError(f"{path}: the mesh has no triangles")
    if len(f) > MAX_MESH_FACES:
        raise InputError(f"{path}: {len(f)} triangles; at most {MAX_MESH_FACES} (decimate it)")
    if not np.isfinite(v).all() or f.min() < 0 or f.max() >= len(v):
        raise InputError(f"{path}: the mesh has non-finite vertices or faces naming missing vertices")
    uv = getattr(getattr(mesh, "visual", None), "uv", None)
    if uv is None or np.asarray(uv).shape != (len(v), 2) or not np.isfinite(np.asarray(uv)).all():
        raise InputError(f"{path}: the mesh has no texture coordinates (one (u, v) per vertex); a head "
                         "mesh needs them for its colour map")
    uv = np.asarray(uv, dtype=np.float64)
    if texture is not None:
        albedo = _read_map(texture, "colour map", colour=True, flip=flip_textures)
    else:
        image = _embedded_texture(mesh)
        if image is None:
            raise InputError(f"{path}: the mesh embeds no colour map; give it with --head-texture FILE")
        from relight.colour import decode_srgb8

        arr = np.asarray(image.convert("RGB"), dtype=np.uint8)
        if max(arr.shape[:2]) > MAX_TEXTURE_SIDE:
            raise InputError(f"{path}: its colour map is {arr.shape[1]}x{arr.shape[0]}; at most {MAX_TEXTURE_SIDE}")
        albedo = decode_srgb8(arr[::-1] if flip_textures else arr).astype(FLOAT)
    if albedo.shape[2] == 1:
        albedo = np.repeat(albedo, 3, axis=2)
    albedo = np.clip(albedo[..., :3], 0.0, 1.0)
    spec = None
    if specular_map is not None:
        spec = _read_map(specular_map, "specular map", colour=False, flip=flip_textures)[..., :3].mean(axis=2)
        spec = np.clip(spec, 0.0, 1.0).astype(FLOAT)
    nmap = None
    if normal_map is not None:
        raw = _read_map(normal_map, "normal map", colour=False, flip=flip_textures)
        if raw.shape[2] < 3:
            raise InputError(f"{normal_map}: a tangent-space normal map has three channels (x, y, z)")
        nmap = 2.0 * raw[..., :3] - 1.0
        if flip_textures:  # green pointed toward the image's top row: turned over, it points the other way
            nmap[..., 1] *= -1.0
        nmap /= np.maximum(np.linalg.norm(nmap, axis=2, keepdims=True), EPS_VALUE)
        nmap = nmap.astype(FLOAT)
    normals, tangents, bitangents = _tangent_frames(v, f, uv)
    sv, sf = v, f
    if len(f) * 4 ** SMOOTH_ITERATIONS <= MAX_SMOOTH_FACES:
        sv, sf = trimesh.remesh.subdivide_loop(v, f, iterations=SMOOTH_ITERATIONS)
    return HeadMesh(vertices=v, faces=f, uv=uv, normals=normals, tangents=tangents, bitangents=bitangents,
                    albedo=np.ascontiguousarray(albedo, dtype=FLOAT), specular=spec, normal_map=nmap,
                    source=str(path), smooth_vertices=np.asarray(sv, np.float64), smooth_faces=np.asarray(sf, np.int64))


def _embedded_texture(mesh):
    """The PIL image of a mesh's own colour map (glTF's base colour texture, OBJ's map_Kd), or None."""
    mat = getattr(getattr(mesh, "visual", None), "material", None)
    for name in ("baseColorTexture", "image"):
        img = getattr(mat, name, None)
        if img is not None:
            return img
    return None


def _tangent_frames(v: np.ndarray, f: np.ndarray, uv: np.ndarray):
    """(normals, tangents, bitangents), each (V, 3) unit: area-weighted vertex normals and the
    directions of +u and +v on the surface (per triangle from its texture coordinates, summed at
    the vertices, made orthogonal to the normal; bitangent = +v's side)."""
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    fn = np.cross(e1, e2)  # length: twice the area
    normals = np.zeros_like(v)
    for k in range(3):
        np.add.at(normals, f[:, k], fn)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), EPS_NORM)
    t0, t1, t2 = uv[f[:, 0]], uv[f[:, 1]], uv[f[:, 2]]
    d1, d2 = t1 - t0, t2 - t0
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    inv = np.where(np.abs(det) > EPS_NORM, 1.0 / np.where(np.abs(det) > EPS_NORM, det, 1.0), 0.0)
    tan = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv[:, None]
    bit = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv[:, None]
    tangents, bitangents = np.zeros_like(v), np.zeros_like(v)
    for k in range(3):
        np.add.at(tangents, f[:, k], tan)
        np.add.at(bitangents, f[:, k], bit)
    tangents -= normals * np.sum(tangents * normals, axis=1, keepdims=True)
    tangents /= np.maximum(np.linalg.norm(tangents, axis=1, keepdims=True), EPS_NORM)
    side = np.sign(np.sum(np.cross(normals, tangents) * bitangents, axis=1))
    bitangents = np.cross(normals, tangents) * np.where(side == 0, 1.0, side)[:, None]
    return normals, tangents, bitangents


def sample_map(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of a texture (h, w, C) at texture coordinates (N, 2) (v up; repeating
    beyond [0, 1], as textures do): (N, C) float32."""
    h, w = img.shape[:2]
    x = (np.mod(uv[:, 0], 1.0)) * (w - 1)
    y = (1.0 - np.mod(uv[:, 1], 1.0)) * (h - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, w - 1)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, h - 1)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bot = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return (top * (1 - fy) + bot * fy).astype(FLOAT)


@dataclass(frozen=True)
class Placement:
    """Mesh -> image: pixel ``(ox + k x, oy - k y)`` and height ``k (z - z0)`` pixels toward the
    camera for a mesh point (x, y, z) at the reference pose; ``center``/``scale`` as
    :class:`.head.Head`'s (the eyes' level, pixels per head unit)."""

    k: float
    ox: float
    oy: float
    z0: float
    center: tuple[float, float]
    scale: float

    def project(self, p: np.ndarray) -> np.ndarray:
        """(N, 3) camera-space pixels (column, -row, height) of mesh points (N, 3)."""
        return np.stack([self.ox + self.k * p[:, 0], -(self.oy - self.k * p[:, 1]), self.k * (p[:, 2] - self.z0)],
                        axis=1)


def place_mesh(mesh: HeadMesh, width: int, height: int) -> Placement:
    """Scale and position the mesh in a ``width x height`` frame (see the module docstring)."""
    from relight import faces
    from relight.colour import encode_srgb8

    (cx, cy), s = head_placement(width, height)
    v = mesh.vertices
    span = float(np.ptp(v[:, :2], axis=0).max())
    if not span > 0:
        raise InputError(f"{mesh.source}: the mesh is flat or a point")
    # A front view where the whole mesh spans ~5 face widths (a head with shoulders fits).
    side = int(PLACEMENT_FACE_PX * 5)
    k = side / span
    lo = v[:, :2].min(axis=0)
    pos = np.stack([(v[:, 0] - lo[0]) * k + 0.5 * (side - np.ptp(v[:, 0]) * k),
                    (v[:, 1].max() - v[:, 1]) * k + 0.5 * (side - np.ptp(v[:, 1]) * k), v[:, 2] * k], axis=1)
    frag = _front_fragments(mesh, pos, side, side)
    view = np.full((side * side, 3), 0.45, dtype=FLOAT)
    if frag is not None:
        cells, tri, w3 = frag
        alb = sample_map(mesh.albedo, _blend(mesh.uv, mesh.faces, tri, w3))
        nz = np.clip(_blend(mesh.normals, mesh.faces, tri, w3)[:, 2], 0.0, 1.0)
        view[cells] = np.clip(alb * (0.25 + 0.9 * nz[:, None]), 0.0, 1.0)
    box = faces.detect_face(encode_srgb8(view.reshape(side, side, 3)))
    if box is None:
        raise InputError(f"{mesh.source}: no face found in a front view of the mesh; a head mesh is +Y up and "
                         "faces +Z (toward the camera) - turn it so, and check its colour map")
    bx, by, bw, _ = box
    kk = FACE_BOX_UNITS * s / (bw / k)  # image pixels per mesh unit
    # the box centre in mesh units, and where it goes in the frame
    mx = (bx + bw / 2.0 - 0.5 * (side - np.ptp(v[:, 0]) * k)) / k + lo[0]
    my = v[:, 1].max() - (by + box[3] / 2.0 - 0.5 * (side - np.ptp(v[:, 1]) * k)) / k
    tx, ty = cx + FACE_BOX_CENTER[0] * s, cy - FACE_BOX_CENTER[1] * s
    return Placement(k=kk, ox=tx - kk * mx, oy=ty + kk * my, z0=float(v[:, 2].min()), center=(float(cx), float(cy)),
                     scale=float(s))


def _blend(attr: np.ndarray, faces: np.ndarray, tri: np.ndarray, w3: np.ndarray) -> np.ndarray:
    """Barycentric blend (N, C) of a per-vertex attribute over fragments' triangles."""
    t = faces[tri]
    return w3[:, 0:1] * attr[t[:, 0]] + w3[:, 1:2] * attr[t[:, 1]] + w3[:, 2:3] * attr[t[:, 2]]


def _front_fragments(mesh: HeadMesh, pos: np.ndarray, gw: int, gh: int, samples: int = 1):
    """Depth-tested fragments of the mesh at vertex positions ``pos`` (V, 3): x, y in pixels
    (rows down), z toward the camera; ``samples`` per pixel side. Returns (sample index,
    triangle, barycentric weights (N, 3)) of the nearest surface at each covered sample, or None."""
    from ..raster import rasterise

    k = samples
    sx, sy = k * (pos[:, 0] + 0.5) - 0.5, k * (pos[:, 1] + 0.5) - 0.5
    cells, z, tri, l0, l1 = rasterise(np.ascontiguousarray(mesh.faces.T), sx, sy, pos[:, 2], gw * k, gh * k)
    if cells.size == 0:
        return None
    zbuf = np.full(gw * k * gh * k, -np.inf)
    np.maximum.at(zbuf, cells, z.astype(np.float64))
    win = np.flatnonzero(z >= zbuf[cells])
    # one fragment per sample (a tie on a shared edge: the first)
    _, first = np.unique(cells[win], return_index=True)
    win = win[first]
    w3 = np.stack([l0[win], l1[win], 1.0 - l0[win] - l1[win]], axis=1).astype(np.float64)
    return cells[win], tri[win], w3


def build_mesh_head(mesh: HeadMesh, width: int, height: int, *, rotation=None,
                    placement: Placement | None = None) -> Head:
    """The mesh as the studio's :class:`.head.Head` on a ``width x height`` grid at the
    reference pose (or turned by ``rotation`` about its placement's origin, for tests)."""
    from relight.kernels.heightfield import NO_SURFACE

    place = placement or place_mesh(mesh, width, height)
    v = mesh.vertices if rotation is None else mesh.vertices @ np.asarray(rotation, np.float64).T
    cam = place.project(v)
    pos = np.stack([cam[:, 0], -cam[:, 1], cam[:, 2]], axis=1)  # (column, row, height)
    frag = _front_fragments(mesh, pos, width, height)
    if frag is None:
        raise InputError(f"{mesh.source}: the mesh falls outside the {width}x{height} frame")
    cells, tri, w3 = frag
    n_pix = width * height
    mask = np.zeros(n_pix, dtype=bool)
    mask[cells] = True
    depth = np.full(n_pix, NO_SURFACE, dtype=np.float64)
    depth[cells] = _blend(pos[:, 2:3], mesh.faces, tri, w3)[:, 0]
    if mesh.smooth_vertices is not None and mesh.smooth_faces is not mesh.faces:
        # the smooth surface's depth where it covers the pixel (it lies within a facet's sag of it)
        sv = mesh.smooth_vertices if rotation is None else mesh.smooth_vertices @ np.asarray(rotation, np.float64).T
        scam = place.project(sv)
        spos = np.stack([scam[:, 0], -scam[:, 1], scam[:, 2]], axis=1)
        sm = _front_fragments(HeadMesh(vertices=sv, faces=mesh.smooth_faces, uv=None, normals=None, tangents=None,
                                       bitangents=None, albedo=None, specular=None, normal_map=None,
                                       source=mesh.source), spos, width, height)
        if sm is not None:
            s_cells, s_tri, s_w3 = sm
            keep = mask[s_cells]
            depth[s_cells[keep]] = _blend(spos[:, 2:3], mesh.smooth_faces, s_tri[keep], s_w3[keep])[:, 0]
    normals = mesh.normals if rotation is None else mesh.normals @ np.asarray(rotation, np.float64).T
    n = _blend(normals, mesh.faces, tri, w3)
    uvp = _blend(mesh.uv, mesh.faces, tri, w3)
    if mesh.normal_map is not None:
        rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
        t = _blend(mesh.tangents @ rot.T, mesh.faces, tri, w3)
        b = _blend(mesh.bitangents @ rot.T, mesh.faces, tri, w3)
        m = sample_map(mesh.normal_map, uvp).astype(np.float64)
        n = t * m[:, 0:1] + b * m[:, 1:2] + n * m[:, 2:3]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), EPS_NORM)
    # Within the steepest slope a height field holds (n_z >= 1 / sqrt(1 + MAX_SLOPE^2)).
    nz_min = 1.0 / np.sqrt(1.0 + MAX_SLOPE ** 2)
    low = n[:, 2] < nz_min
    if low.any():
        lat = n[low, :2] / np.maximum(np.linalg.norm(n[low, :2], axis=1, keepdims=True), EPS_NORM)
        n[low, :2] = lat * np.sqrt(1.0 - nz_min ** 2)
        n[low, 2] = nz_min
    normal = np.zeros((n_pix, 3), dtype=FLOAT)
    normal[cells] = n
    albedo = np.zeros((n_pix, 3), dtype=FLOAT)
    albedo[cells] = np.clip(sample_map(mesh.albedo, uvp), 0.0, 1.0)
    spec = np.zeros(n_pix, dtype=FLOAT)
    spec[cells] = SKIN_SPECULAR if mesh.specular is None else \
        SPECULAR_MAP_MAX * sample_map(mesh.specular[..., None], uvp)[:, 0]
    # Coverage: the share of 4x4 samples any surface covers.
    k = ALPHA_SUPERSAMPLE
    sub = _front_fragments(mesh, pos, width, height, samples=k)
    cover = np.zeros((height * k, width * k), dtype=np.float32)
    if sub is not None:
        cover.reshape(-1)[sub[0]] = 1.0
    alpha = cover.reshape(height, k, width, k).mean(axis=(1, 3))
    shape = (height, width)
    return Head(height=depth.reshape(shape).astype(FLOAT), alpha=alpha.astype(FLOAT), mask=mask.reshape(shape),
                normal=normal.reshape(*shape, 3), albedo=albedo.reshape(*shape, 3),
                specular=spec.reshape(shape), roughness=np.full(shape, SKIN_ROUGHNESS, dtype=FLOAT),
                wrap=np.broadcast_to(np.asarray(SKIN_WRAP, FLOAT), (*shape, 3)).copy(),
                center=place.center, scale=place.scale, regions={})
