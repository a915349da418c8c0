"""``relight capture --report DIR``: report.json and the plots a person wants to look at.

report.json keys: ``flash_frames``, ``light_dirs`` {frame: [x, y, z]}, ``transforms``
{frame: [tx, ty, rot_deg]} (about ``transform_center``), ``reference_frame``, ``rejected``
{reason: count}, ``timings`` {stage: s}, plus the flash rate, sphere, face box and notes.

Plots (PNG): brightness.png (trace with the flash and no-flash picks), registration.png
(drift over time), directions.png (samples, virtual black lights and the triangulation on a
lat-long map), normals.png, maps.png (reflectance maps of a few pixels) and visibility.png.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from relight.directions import direction_to_equirect_uv
from relight.imageio import atomic_path, write_image
from relight.kernels.bundle_format import Field
from relight.numerics import EPS_VALUE


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    _plt().close(fig)


def write_report(folder, result, geo, tri) -> Path:
    """Write report.json and the PNG plots for a capture result into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rep = result.report
    public = {k: v for k, v in rep.items() if not k.startswith("_")}
    if "_trace" in rep:
        public["brightness_trace"] = [round(float(x), 6) for x in rep["_trace"]]
    with atomic_path(folder / "report.json") as tmp:
        tmp.write_text(json.dumps(public, indent=1))
    plt = _plt()
    if "_trace" in rep:
        _brightness(plt, rep, folder / "brightness.png")
        _registration(plt, rep, folder / "registration.png")
    _directions(plt, tri, folder / "directions.png")
    n = geo.normal
    write_image(folder / "normals.png", np.round((n * 0.5 + 0.5) * 255 * geo.mask[..., None]).astype(np.uint8))
    picks = _maps(plt, result.arrays, result.meta, tri, geo, folder / "maps.png")
    _visibility(plt, result.arrays, tri, geo, picks, folder / "visibility.png")
    return folder


def _brightness(plt, rep, path):
    trace = np.asarray(rep["_trace"])
    fig, ax = plt.subplots(figsize=(12, 3.2))
    t = np.arange(trace.size)
    ax.plot(t, trace, lw=0.7, color="0.3", label="mean face brightness (linear)")
    fl = np.asarray(rep["flash_frames"], dtype=int)
    pk = np.asarray(rep["flash_peaks"], dtype=int)
    dk = np.asarray(rep["dark_frames"], dtype=int)
    ax.plot(fl, trace[fl], ".", ms=3, color="tab:orange", label="flash frames")
    ax.plot(pk, trace[pk], "^", ms=4, color="tab:red", label="flash peaks")
    ax.plot(dk, trace[dk], ".", ms=3, color="tab:blue", label="no-flash frames")
    ax.set_xlabel("frame")
    ax.set_title(f"flash separation: {len(pk)} flashes at {rep['flash_hz']:.2f} Hz"
                 + (" (estimated)" if rep.get("flash_hz_estimated") else ""))
    ax.legend(loc="upper right", fontsize=7, ncols=4)
    _save(fig, path)


def _registration(plt, rep, path):
    tr = rep["transforms"]
    frames = np.array(sorted(int(k) for k in tr))
    vals = np.array([tr[str(f)] for f in frames])
    dark = set(rep["dark_frames"])
    is_dark = np.array([f in dark for f in frames])
    fig, axes = plt.subplots(2, 1, figsize=(12, 4.5), sharex=True)
    axes[0].plot(frames, vals[:, 0], lw=0.8, label="tx (px)")
    axes[0].plot(frames, vals[:, 1], lw=0.8, label="ty (px)")
    axes[0].plot(frames[is_dark], vals[is_dark, 0], ".", ms=2, color="k")
    axes[0].legend(fontsize=7)
    axes[0].set_title(f"head motion relative to reference frame {rep['reference_frame']} "
                      "(dots: tracked no-flash frames; lines: interpolated)")
    axes[1].plot(frames, vals[:, 2], lw=0.8, color="tab:green", label="rotation (deg)")
    axes[1].legend(fontsize=7)
    axes[1].set_xlabel("frame")
    _save(fig, path)


def _directions(plt, tri, path):
    fig, ax = plt.subplots(figsize=(10, 5))
    u, v = direction_to_equirect_uv(tri.vertices)
    for f in tri.faces:
        uu, vv = u[f], v[f]
        if np.ptp(uu) > 0.5:  # wraps around the map's seam
            continue
        real = (f < tri.n_samples).sum()
        ax.fill(uu, vv, fill=False, lw=0.3, color="0.6" if real < 3 else "0.35")
    ax.plot(u[:tri.n_samples], v[:tri.n_samples], "o", ms=3, color="tab:orange", label="flash samples")
    ax.plot(u[tri.n_samples:], v[tri.n_samples:], "x", ms=3, color="0.5", label="virtual lights beyond the hull")
    ax.set_xlim(0, 1)
    ax.set_ylim(1, 0)
    ax.set_xticks([0, 0.25, 0.5, 0.75, 1], ["-Z", "+X", "+Z (camera)", "-X", "-Z"])
    ax.set_yticks([0, 0.5, 1], ["+Y", "0", "-Y"])
    ax.set_title(f"{tri.n_samples} light directions on the lat-long map, spherical Delaunay triangulation")
    ax.legend(fontsize=7, loc="lower right")
    _save(fig, path)


def _maps(plt, arrays, meta, tri, geo, path):
    texels = arrays[Field.MAP_TEXELS]
    pix = arrays[Field.PIXELS]
    h, w = geo.mask.shape
    ys, xs = pix // w, pix % w
    picks = []
    for qx, qy in ((0.5, 0.3), (0.5, 0.55), (0.3, 0.55), (0.5, 0.8)):
        tx, ty = xs.min() + qx * np.ptp(xs), ys.min() + qy * np.ptp(ys)
        picks.append(int(np.argmin((xs - tx) ** 2 + (ys - ty) ** 2)))
    mw, mh = tri.map_size
    if Field.MAPS_ROWS in arrays:
        maps = np.asarray(arrays[Field.MAPS_ROWS][:, :, picks], dtype=np.float32).transpose(2, 1, 0)  # (n, 3, T)
    else:  # made again from the bundle's recipe, as a user's bundle would
        from relight.kernels.recipe import recipe_from_arrays, recipe_maps

        rec = recipe_from_arrays(arrays, meta, tri.map_size).subset(np.asarray(picks))
        maps = recipe_maps(rec, half=False)[:, :, :texels.size]
    fig, axes = plt.subplots(2, len(picks), figsize=(3.2 * len(picks), 4))
    for j, p in enumerate(picks):
        full = np.zeros((mh * mw, 3), dtype=np.float32)
        full[texels] = maps[j].T
        img = full.reshape(mh, mw, 3)
        axes[0, j].imshow(np.clip(img / max(float(img.max()), EPS_VALUE), 0, 1) ** (1 / 2.2))
        axes[0, j].set_title(f"pixel ({xs[p]}, {ys[p]})", fontsize=8)
        axes[0, j].axis("off")
        axes[1, j].imshow(geo.mask, cmap="gray")
        axes[1, j].plot([xs[p]], [ys[p]], "r+", ms=10)
        axes[1, j].axis("off")
    fig.suptitle("reflectance maps (lat-long, +Z at the centre) of a few head pixels")
    _save(fig, path)
    return picks


def _visibility(plt, arrays, tri, geo, picks, path):
    from relight.kernels.heightfield import HORIZON_DIRS, NO_SURFACE, horizon_table
    from relight.kernels.interpolation import visibility_maps

    pix = arrays[Field.PIXELS]
    hgt = np.where(geo.mask, geo.depth, NO_SURFACE).astype(np.float32)
    sel = pix[picks].astype(np.int32)
    vis = visibility_maps(np.arctan(horizon_table(hgt, sel, HORIZON_DIRS)), HORIZON_DIRS, tri.map_size)
    h, w = geo.mask.shape
    fig, axes = plt.subplots(1, len(picks), figsize=(3.2 * len(picks), 2.2))
    for j, p in enumerate(sel):
        axes[j].imshow(vis[j], cmap="gray", vmin=0, vmax=1)
        axes[j].set_title(f"pixel ({p % w}, {p // w})", fontsize=8)
        axes[j].axis("off")
    fig.suptitle("visibility maps from the estimated height field (white: the light reaches the pixel)")
    _save(fig, path)
