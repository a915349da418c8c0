"""A contact sheet of a synthetic capture: what a person checks first, on one PNG.

Rows: the reference (no-flash) frame and three flash frames; the mirror sphere in each
(highlight position predicted from the truth's light direction marked with a ring); the
truth relit under each truth environment; normals, albedo, a one-light image and the
sampled flash directions on a lat-long map.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from relight.colour import encode_srgb8
from relight.directions import direction_to_equirect_uv, sphere_point_for_light
from relight.imageio import read_image, write_image
from relight.numerics import EPS_VALUE
from relight.video_read import read_frames

TILE = (480, 270)


def _fit(img: np.ndarray, size=TILE) -> np.ndarray:
    """Scale an RGB uint8 image to fit in ``size`` (w, h), centred on black."""
    w, h = size
    s = min(w / img.shape[1], h / img.shape[0])
    nw, nh = max(int(img.shape[1] * s), 1), max(int(img.shape[0] * s), 1)
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_NEAREST
    small = cv2.resize(img, (nw, nh), interpolation=interp)
    out = np.zeros((h, w, 3), dtype=np.uint8)
    y0, x0 = (h - nh) // 2, (w - nw) // 2
    out[y0:y0 + nh, x0:x0 + nw] = small
    return out


def _label(tile: np.ndarray, text: str) -> np.ndarray:
    tile = tile.copy()
    cv2.rectangle(tile, (0, 0), (tile.shape[1], 18), (0, 0, 0), -1)
    cv2.putText(tile, text, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
    return tile


def _footer(width: int, text: str | None) -> np.ndarray | None:
    """A strip (rows, width, 3) uint8 with ``text`` wrapped to the width (a credit line), or None."""
    if not text:
        return None
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.42
    lines, line = [], ""
    for word in text.split():
        trial = f"{line} {word}".strip()
        if line and cv2.getTextSize(trial, font, scale, 1)[0][0] > width - 8:
            lines.append(line)
            line = word
        else:
            line = trial
    lines.append(line)
    strip = np.zeros((8 + 16 * len(lines), width, 3), dtype=np.uint8)
    for k, ln in enumerate(lines):
        cv2.putText(strip, ln, (4, 17 + 16 * k), font, scale, (220, 220, 220), 1, cv2.LINE_AA)
    return strip


def _with_footer(sheet: np.ndarray, credit: str | None) -> np.ndarray:
    strip = _footer(sheet.shape[1], credit)
    return sheet if strip is None else np.concatenate([sheet, strip], axis=0)


def _tonemap(linear: np.ndarray, mask: np.ndarray) -> np.ndarray:
    vals = linear[mask].max(axis=1) if mask.any() else linear.reshape(-1, 3).max(axis=1)
    scale = 0.8 / max(float(np.percentile(vals, 98)), EPS_VALUE)
    return encode_srgb8(linear * scale)


def contact_sheet(capture: str | Path, out: str | Path, bundle=None) -> Path:
    """Write the contact sheet of the capture folder ``capture`` (from ``relight synth``) to ``out``.

    With a ``bundle`` made from that capture, a last row compares it with the truth: estimated
    normals, a reflectance map, and a one-light image predicted from the bundle beside the truth's.
    """
    capture = Path(capture)
    meta = json.loads((capture / "truth" / "meta.json").read_text())
    ref = meta["reference_frame"]
    flashes = meta["flash_frames"]
    picks = [ref] + [flashes[int(i)] for i in np.linspace(0, len(flashes) - 1, 3)] if flashes else [ref]
    wanted = set(picks)
    frames = {}
    for i, f in enumerate(read_frames(capture / meta["files"]["video"])):
        if i in wanted:
            frames[i] = f
        if len(frames) == len(wanted):
            break
    cx, cy, r = meta["sphere"]
    rows = []
    row1, row2 = [], []
    for i in picks:
        f = frames[i]
        d = meta["light_dirs"].get(str(i))
        text = f"frame {i} (reference, no flash)" if d is None else \
            f"frame {i}, light ({d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f})"
        row1.append(_label(_fit(f), text))
        pad = int(1.3 * r)
        x0, y0 = int(cx) - pad, int(cy) - pad
        crop = np.ascontiguousarray(f[max(y0, 0):int(cy) + pad, max(x0, 0):int(cx) + pad])
        scale = TILE[1] / crop.shape[0]
        big = cv2.resize(crop, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        if d is not None:
            px, py = sphere_point_for_light(np.asarray(d), (cx, cy, r))
            c = (int(round((px - max(x0, 0) + 0.5) * scale - 0.5)), int(round((py - max(y0, 0) + 0.5) * scale - 0.5)))
            cv2.circle(big, c, int(6 * scale / 2), (0, 255, 0), 1, cv2.LINE_AA)
        row2.append(_label(_fit(big), f"sphere, frame {i}" + (" (ring: truth)" if d else "")))
    rows += [row1, row2]
    mask = cv2.imread(str(capture / meta["files"]["mask"]), cv2.IMREAD_GRAYSCALE) > 0
    ys, xs = np.nonzero(mask)
    bb = (slice(max(ys.min() - 4, 0), ys.max() + 5), slice(max(xs.min() - 4, 0), xs.max() + 5))
    row3 = []
    for name, rel in meta["files"]["relit"].items():
        img = read_image(capture / rel)
        row3.append(_label(_fit(_tonemap(img, mask)[bb]), f"truth relit: {name}"))
    rows.append(row3)
    normals = read_image(capture / meta["files"]["normals"])
    albedo = read_image(capture / meta["files"]["albedo"])
    olat_name, olat_rel = next(iter(meta["files"]["olat"].items()))
    olat_name = "olat_side" if "olat_side" in meta["files"]["olat"] else olat_name
    olat = read_image(capture / meta["files"]["olat"][olat_name])
    row4 = [
        _label(_fit(np.round(np.clip(normals * 0.5 + 0.5, 0, 1) * 255 * mask[..., None]).astype(np.uint8)[bb]),
               "truth normals (xyz -> rgb)"),
        _label(_fit(encode_srgb8(albedo)[bb]), "truth albedo"),
        _label(_fit(_tonemap(olat, mask)[bb]), f"truth {olat_name}"),
        _label(_directions_plot(meta), f"{len(meta['light_dirs'])} flash directions (lat-long)"),
    ]
    rows.append(row4)
    if bundle is not None:
        rows.append(_bundle_row(bundle, meta, capture, mask, bb))
    width = max(len(r_) for r_ in rows)
    blank = np.zeros((TILE[1], TILE[0], 3), dtype=np.uint8)
    sheet = np.concatenate([np.concatenate(r_ + [blank] * (width - len(r_)), axis=1) for r_ in rows], axis=0)
    return write_image(out, _with_footer(sheet, (meta.get("head") or {}).get("credit")))


def _directions_plot(meta: dict) -> np.ndarray:
    w, h = TILE[0], TILE[0] // 2
    img = np.full((h, w, 3), 30, dtype=np.uint8)
    for frac in (0.25, 0.5, 0.75):
        cv2.line(img, (int(frac * w), 0), (int(frac * w), h), (70, 70, 70), 1)
    cv2.line(img, (0, h // 2), (w, h // 2), (70, 70, 70), 1)
    for d in meta["light_dirs"].values():
        u, v = direction_to_equirect_uv(np.asarray(d))
        cv2.circle(img, (int(u * w), int(v * h)), 2, (255, 200, 60), -1, cv2.LINE_AA)
    for text, frac in (("-X", 0.75), ("+Z", 0.5), ("+X", 0.25)):
        cv2.putText(img, text, (int(frac * w) + 3, h - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (200, 200, 200), 1)
    return _fit(img)


def sample_map(maps: np.ndarray, tri_active: np.ndarray, map_size: tuple[int, int], direction) -> np.ndarray:
    """Bilinear lookup of pixel-major reflectance maps (P, 3, T_pad) toward one direction: (P, 3)."""
    w, h = map_size
    u, v = direction_to_equirect_uv(np.asarray(direction, dtype=np.float64))
    x = float(u) * w - 0.5
    y = min(max(float(v) * h - 0.5, 0.0), h - 1.0)
    x0 = int(np.floor(x))
    y0 = int(np.floor(y))
    fx, fy = x - x0, y - y0
    lut = -np.ones(w * h, dtype=np.int64)
    lut[np.flatnonzero(tri_active)] = np.arange(int(tri_active.sum()))
    out = np.zeros(maps.shape[:2], dtype=np.float64)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            yy = min(y0 + dy, h - 1)
            xx = (x0 + dx) % w
            t = lut[yy * w + xx]
            if t >= 0 and wx * wy > 0:
                out += wx * wy * np.asarray(maps[:, :, t], dtype=np.float64)
    return out.astype(np.float32)


def _bundle_row(bundle, meta, capture, mask, bb) -> list:
    """Estimated normals, a reflectance map, and a predicted one-light image next to the truth's."""
    h, w = mask.shape
    x0, y0 = bundle.crop_origin
    crop = np.asarray(bundle.mask_crop)
    ch, cw = crop.shape
    pix = np.asarray(bundle.pixels)
    normals = np.zeros((ch * cw, 3), dtype=np.float32)
    normals[pix] = np.asarray(bundle.normal)
    full_n = np.zeros((h, w, 3), dtype=np.float32)
    full_n[y0:y0 + ch, x0:x0 + cw] = normals.reshape(ch, cw, 3)
    has = np.zeros((h, w), dtype=bool)
    has[y0:y0 + ch, x0:x0 + cw] = crop
    name = "olat_left" if "olat_left" in meta["files"]["olat"] else next(iter(meta["files"]["olat"]))
    truth = read_image(capture / meta["files"]["olat"][name])
    active = np.zeros(bundle.map_size[0] * bundle.map_size[1], dtype=bool)
    active[np.asarray(bundle.map_texels)] = True
    pred_p = sample_map(bundle.pixel_maps().astype(np.float32), active, bundle.map_size, meta["olat_dirs"][name])
    pred = np.zeros((h, w, 3), dtype=np.float32)
    pc = np.zeros((ch * cw, 3), dtype=np.float32)
    pc[pix] = pred_p
    pred[y0:y0 + ch, x0:x0 + cw] = pc.reshape(ch, cw, 3)
    scale = 0.8 / max(float(np.percentile(truth[mask].max(axis=1), 98)), EPS_VALUE)
    cheek = int(np.argmin(np.abs(pix - (ch // 2 * cw + cw // 3))))
    rmap = bundle.full_map(cheek)
    rmap_img = encode_srgb8(rmap / max(float(rmap.max()), EPS_VALUE))
    return [
        _label(_fit(np.round(np.clip(full_n * 0.5 + 0.5, 0, 1) * 255 * has[..., None]).astype(np.uint8)[bb]),
               "captured normals (photometric stereo)"),
        _label(_fit(cv2.resize(rmap_img, (TILE[0], TILE[0] // 2), interpolation=cv2.INTER_NEAREST)),
               "captured reflectance map of one pixel"),
        _label(_fit(encode_srgb8(pred * scale)[bb]), f"{name} predicted from the bundle"),
        _label(_fit(encode_srgb8(truth * scale)[bb]), f"{name} truth"),
    ]


def before_after_sheet(before: str | Path, relit: dict[str, str | Path], out: str | Path,
                       rows: int = 3, credit: str | None = None) -> Path:
    """A PNG of ``rows`` moments of a clip: the camera's frame, then the same frame in each relit
    clip (``relit``: label -> video, e.g. one per environment; same frame count as ``before``);
    ``credit``: a line under it (whose head it shows)."""
    clips = {"before": Path(before), **{k: Path(v) for k, v in relit.items()}}
    frames = {k: list(read_frames(v)) for k, v in clips.items()}
    n = min(len(f) for f in frames.values())
    if n == 0:
        raise ValueError(f"{before}: no frames")
    picks = np.linspace(0, n - 1, rows + 2)[1:-1].round().astype(int)
    grid = []
    for i in picks:
        grid.append(np.concatenate([_label(_fit(frames[k][i]), f"{k}  (frame {i})") for k in clips], axis=1))
    write_image(out, _with_footer(np.concatenate(grid, axis=0), credit))
    return Path(out)
