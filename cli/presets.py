"""``relight presets``: one face under every built-in light and preset, as a contact sheet."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from relight.envmap import BUILTINS
from relight.presets import PRESETS

from .common import COMMANDS

#: The sheet's lights, in its order: the presets people recognise, the key light's defaults, then
#: the studio's own built-ins (uniform, the plainest, last) - from their registries.
SHEET_LIGHTS = (*PRESETS, "key", *sorted(BUILTINS, key=lambda name: name == "uniform"))
#: Each tile's face is brought to this median luminance (linear): the sheet shows each light's
#: direction, softness and colour, as relight live's exposure matching would show them, not its
#: power (a stage spot and an overcast sky differ by stops).
TILE_MEDIAN = 0.18


def add_parser(sub) -> None:
    p = sub.add_parser(
        "presets", help=COMMANDS["presets"],
        description="Relight a bundle's face under every built-in light - the presets people recognise "
                    "(overcast, golden-hour, office, stage, ring-light), the key light's defaults "
                    "(builtin:key) and the studio's built-ins - and write them side by side as one "
                    "labelled contact sheet. Each face is exposed to the same median brightness, so the "
                    "sheet compares the lights' direction, softness and colour.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--bundle", type=Path, required=True, help="reflectance bundle (relight capture)")
    p.add_argument("-o", "--out", type=Path, required=True, help="the sheet to write (.png or .jpg)")
    p.add_argument("--tile", type=int, default=256, help="each face's tile height in pixels (64 to 1024)")
    p.add_argument("--columns", type=int, default=4, help="tiles per row (1 to 12)")
    p.set_defaults(func=_run_presets)


def preset_sheet(bundle, tile: int = 256, columns: int = 4, lights=SHEET_LIGHTS) -> np.ndarray:
    """(H, W, 3) uint8 sRGB contact sheet of ``bundle``'s face under each of ``lights``
    (``builtin:`` names), labelled, each face cropped to its box and exposed to TILE_MEDIAN."""
    import cv2

    from .. import load_environment
    from ..colour import LUMINANCE, encode_srgb8
    from ..kernels.relighter import Relighter

    r = Relighter(bundle)
    mask = np.asarray(bundle.mask, bool)
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    y0, y1, x0, x1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    side = max(y1 - y0, x1 - x0)
    cy, cx = (y0 + y1) // 2, (x0 + x1) // 2
    half = int(side * 0.55)
    label_h = max(18, tile // 9)
    tiles = []
    for name in lights:
        img = np.asarray(r.relight(load_environment(f"builtin:{name}")), dtype=np.float32)
        med = float(np.median(img[mask] @ LUMINANCE))
        img = img * np.float32(TILE_MEDIAN / med) if med > 1e-8 else img
        pad = np.zeros((img.shape[0] + 2 * half, img.shape[1] + 2 * half, 3), np.float32)
        pad[half:half + img.shape[0], half:half + img.shape[1]] = img
        crop = pad[cy:cy + 2 * half, cx:cx + 2 * half]  # (the pad's offset cancels the centre's)
        face = cv2.resize(encode_srgb8(np.clip(crop, 0.0, 1.0)), (tile, tile), interpolation=cv2.INTER_AREA)
        label = np.full((label_h, tile, 3), 24, np.uint8)
        scale = label_h / 40.0
        cv2.putText(label, name, (6, int(label_h * 0.72)), cv2.FONT_HERSHEY_SIMPLEX, scale, (235, 235, 235),
                    max(1, int(round(scale * 2))), cv2.LINE_AA)
        tiles.append(np.vstack([face, label]))
    n_rows = -(-len(tiles) // columns)
    blank = np.full_like(tiles[0], 24)
    tiles += [blank] * (n_rows * columns - len(tiles))
    return np.vstack([np.hstack(tiles[i * columns:(i + 1) * columns]) for i in range(n_rows)])


def _run_presets(args) -> int:
    import cv2

    from .. import load_bundle
    from ..errors import InputError
    from ..imageio import atomic_path

    if not (64 <= args.tile <= 1024):
        raise InputError(f"--tile {args.tile}: use 64 to 1024 pixels")
    if not (1 <= args.columns <= 12):
        raise InputError(f"--columns {args.columns}: use 1 to 12")
    if args.out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise InputError(f"{args.out}: write a .png or .jpg sheet")
    t0 = time.perf_counter()
    sheet = preset_sheet(load_bundle(args.bundle), args.tile, args.columns)
    with atomic_path(args.out) as tmp:
        ok, buf = cv2.imencode(args.out.suffix.lower(), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
        if not ok:  # pragma: no cover - OpenCV encodes every uint8 RGB image
            raise InputError(f"{args.out}: could not encode the sheet")
        Path(tmp).write_bytes(buf.tobytes())
    print(f"wrote {args.out} ({len(SHEET_LIGHTS)} lights, {sheet.shape[1]}x{sheet.shape[0]}; "
          f"{time.perf_counter() - t0:.1f} s)")
    return 0
