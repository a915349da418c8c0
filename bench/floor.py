"""The machine's floor for a live frame, measured beside the benchmarks that compare against it
(issue 48): what decoding a clip costs alone, and decoding plus one pass of a constant light field
over a person-sized box in the decoder's planes - the least any relit frame can cost here.

CPU = user + sys of every thread of this process (``time.process_time``), ms per frame; the clip
decoded from the file as the camera reader does (threaded H.264 into Y'CbCr planes).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

#: The constant field's box: this share of the frame's width and height, centred (the person's
#: box at 720p is ~768x648 of 1280x720).
BOX_SHARE = (0.6, 0.9)


def _decoded(clip: Path, limit: int):
    """Decoded frames of ``clip`` kept in their planes (at most ``limit``), as the camera reader
    keeps them."""
    from relight.video_read import read_frames_raw
    from relight.video_yuv import YuvFrame

    for i, frame in enumerate(read_frames_raw(clip)):
        if i >= limit:
            return
        yield YuvFrame.from_av(frame)


def constant_field(size: tuple[int, int]):
    """(grid, box, factor, corner): a constant light field (a gain of 1.3 and a warm tint, as maps of
    BT.709 codes) over a centred box of ``size`` (w, h) (:data:`BOX_SHARE`), at the field's own
    factor there."""
    from relight.engine.field import code_grid, field_factor
    from relight.video_yuv import BT709

    w, h = size
    f = field_factor(size)
    bw, bh = int(w * BOX_SHARE[0]) // f * f, int(h * BOX_SHARE[1]) // f * f
    x0, y0 = (w - bw) // 2 // f * f, (h - bh) // 2 // f * f
    gh, gw = bh // f, bw // f
    cells = np.zeros((gh, gw, 8), np.float32)
    cells[..., :3] = (1.4, 1.3, 1.1)
    cells[..., 3] = 1.0
    colour = np.full((gh, gw, 3), 120, np.uint8)
    grid = code_grid(cells, colour, *BT709.maps())
    grid.flags.writeable = False
    return grid, (x0, y0, x0 + bw, y0 + bh), f, (x0, y0)


def measure(clip: Path, *, frames: int = 300, runs: int = 3) -> dict:
    """The floor of ``clip``: medians over ``runs`` of decode alone and decode plus the constant
    field (ms of CPU per frame), and the frames timed."""
    from relight.kernels.field_apply import FieldApplier

    first = next(_decoded(Path(clip), 1))
    size = (first.shape[1], first.shape[0])
    grid, box, factor, corner = constant_field(size)
    applier = FieldApplier()
    applier.planes(first.y, first.u, first.v, box, grid, factor, corner)  # (built and run once: no compile timed)
    decode, field = [], []
    n = 0
    for _ in range(runs):
        c0 = time.process_time()
        n = sum(1 for _ in _decoded(Path(clip), frames))
        decode.append(1e3 * (time.process_time() - c0) / max(n, 1))
        c0 = time.process_time()
        for f in _decoded(Path(clip), frames):
            f.with_field(applier, box, grid, factor, corner)
        field.append(1e3 * (time.process_time() - c0) / max(n, 1))
    return {"size": list(size), "frames": n, "runs": runs, "box": list(box),
            "decode_cpu_ms": float(np.median(decode)), "decode_field_cpu_ms": float(np.median(field)),
            "field_cpu_ms": float(np.median(field) - np.median(decode))}


def line(doc: dict) -> str:
    """One line of the floor for a table."""
    w, h = doc["size"]
    return (f"floor at {w}x{h} (median of {doc['runs']}, {doc['frames']} frames): decode alone "
            f"{doc['decode_cpu_ms']:.1f} ms CPU a frame ({doc['decode_cpu_ms'] * 3:.0f} % of a core at 30 fps); "
            f"decode + a constant field over a {doc['box'][2] - doc['box'][0]}x{doc['box'][3] - doc['box'][1]} box "
            f"{doc['decode_field_cpu_ms']:.1f} ms ({doc['decode_field_cpu_ms'] * 3:.0f} %)")
