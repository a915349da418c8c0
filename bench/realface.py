"""Real faces in video, for ``relight bench video``: clips made from real single-light photos.

A real face under a light from one side, moving a little, relit toward another light - the case
a live call in a room with a window is. From an RTI set of a real face (``../shared/data/
faces-yale``: 47-49 photos, each under one known light):

* the set is split as the accuracy report does (every ``FACE_HOLDOUT``-th light held out) and
  the rest builds a bundle (``relight capture --images``);
* light A: a strong side light - the largest ``|x|`` among the captured lights with ``z > 0.5``;
  light B: the held-out light farthest from A;
* the clip: the photo under A (decoded with the set's transfer curve, sRGB-encoded as a camera
  delivers it) centred on a plain ``CANVAS`` frame and moved in the image plane (``CLIP_FRAMES``
  frames at ``CLIP_FPS`` fps: shift, roll and scale, smooth, spanning +-``SHIFT_PX`` px,
  +-``ROLL_DEG`` deg, +-``SCALE`` of scale); the truth: the photo under B moved the same way;
* filtered with ``relight filter --env builtin:point:B --fixed-env`` (the light moves with the
  face in such a clip) in each ``--mode``; and the still prediction of B (``render --light B``)
  moved the same way;
* metric: PSNR over the face pixels of every frame (sRGB 0-1) after one least-squares gain (in
  linear light) for the whole clip; and the frames where a face was found.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from relight.engine.composite import DEFAULT_REGION, MODES

#: The clip: frames, rate, canvas (rows, columns), motion amplitudes, canvas level (sRGB code).
CLIP_FRAMES = 50
CLIP_FPS = 25
CANVAS = (288, 320)
SHIFT_PX = 14.0
ROLL_DEG = 4.0
SCALE = 0.05
CANVAS_CODE = 64
#: Face pixels scored: the photo's frame eroded by this many pixels (its warped edge blends
#: with the canvas).
EDGE_PX = 3


def clip_motion(n: int = CLIP_FRAMES) -> np.ndarray:
    """(n, 4) per frame: tx, ty (px), roll (deg, counter-clockwise on screen), scale. Smooth sums
    of sines of incommensurate frequencies, each spanning its full range over the clip."""
    t = np.arange(n) / max(n - 1, 1)
    out = np.zeros((n, 4))
    for j, (amp, f1, f2, ph) in enumerate(((SHIFT_PX, 1.0, 2.3, 0.3), (SHIFT_PX, 1.4, 0.6, 1.9),
                                           (ROLL_DEG, 1.2, 2.9, 0.8), (SCALE, 0.8, 1.7, 2.6))):
        v = np.sin(2 * np.pi * f1 * t + ph) + 0.5 * np.sin(2 * np.pi * f2 * t + 2 * ph)
        v = (v - v.min()) / max(float(np.ptp(v)), 1e-12) * 2.0 - 1.0  # exactly +-1 over the clip
        out[:, j] = amp * v
    out[:, 3] += 1.0
    return out


def place(image: np.ndarray, m, canvas=CANVAS, fill: float = 0.0, interpolation=cv2.INTER_LINEAR) -> np.ndarray:
    """``image`` (h, w, C) centred on a ``canvas`` (rows, columns) frame, moved by ``m`` = (tx,
    ty, roll, scale) about its centre; ``fill`` outside."""
    h, w = image.shape[:2]
    rows, cols = canvas
    tx, ty, roll, sc = (float(v) for v in m)
    a = cv2.getRotationMatrix2D((w / 2.0, h / 2.0), roll, sc)
    a[:, 2] += (cols / 2.0 - w / 2.0 + tx, rows / 2.0 - h / 2.0 + ty)
    img = np.ascontiguousarray(image, dtype=np.float32)
    out = cv2.warpAffine(img, a, (cols, rows), flags=interpolation, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=(fill,) * 4)
    return out.reshape(rows, cols, *image.shape[2:])


def pick_lights(train: list, held: list) -> tuple[tuple[str, np.ndarray], tuple[str, np.ndarray]]:
    """(A, B): A the captured light with the largest |x| among z > 0.5; B the held-out light
    farthest from A. Each (file name, direction)."""
    side = [e for e in train if e[1][2] > 0.5] or list(train)
    a = max(side, key=lambda e: abs(float(e[1][0])))
    b = min(held, key=lambda e: float(np.dot(e[1], a[1])))
    return a, b


def make_clip(folder: Path, out: Path, transfer: str) -> dict:
    """The clip of one subject (see the module docstring): ``out/clip.mp4`` (H.264, sRGB),
    ``out/truth.npz`` (the truth frames under B, linear, and the face masks). Returns a dict of
    what was made."""
    from relight.bench.accuracy_real import FACE_HOLDOUT
    from relight.colour import encode_srgb8
    from relight.pipeline.image_set import read_lp, read_set_image
    from relight.video_write import VideoWriter

    entries = read_lp(folder / "dirs.lp")
    train = [e for i, e in enumerate(entries) if i % FACE_HOLDOUT != 0]
    held = [e for i, e in enumerate(entries) if i % FACE_HOLDOUT == 0]
    (a_name, a_dir), (b_name, b_dir) = pick_lights(train, held)
    photo_a = read_set_image(folder / a_name, transfer)[0]
    photo_b = read_set_image(folder / b_name, transfer)[0]
    ambient = next((read_set_image(folder / n, transfer)[0] for n in ("ambient.png",) if (folder / n).exists()),
                   None)
    motion = clip_motion()
    fill = float((CANVAS_CODE / 255.0 + 0.055) / 1.055) ** 2.4  # the canvas in linear light
    face = np.ones(photo_a.shape[:2], np.float32)
    out.mkdir(parents=True, exist_ok=True)
    truth, masks = [], []
    with VideoWriter(out / "clip.mp4", CLIP_FPS, (CANVAS[1], CANVAS[0]), crf=12) as wr:
        for m in motion:
            wr.write(encode_srgb8(place(photo_a, m, fill=fill)))
            truth.append(place(photo_b, m, fill=fill))
            cover = place(face, m, interpolation=cv2.INTER_NEAREST) > 0.5
            masks.append(cv2.erode(cover.astype(np.uint8), np.ones((2 * EDGE_PX + 1,) * 2, np.uint8)) > 0)
    np.savez_compressed(out / "truth.npz", truth=np.stack(truth).astype(np.float16), masks=np.stack(masks),
                        motion=motion)
    return {"light_a": a_name, "dir_a": [round(float(x), 6) for x in a_dir], "light_b": b_name,
            "dir_b": [round(float(x), 6) for x in b_dir], "ambient": ambient is not None,
            "angle_deg": float(np.degrees(np.arccos(np.clip(np.dot(a_dir, b_dir), -1, 1))))}


def clip_psnr(frames_srgb: list[np.ndarray], truth_lin: np.ndarray, masks: np.ndarray) -> float:
    """PSNR (dB, sRGB 0-1) over the face pixels of every frame after one least-squares gain in
    linear light for the whole clip."""
    return clip_psnr_gain(frames_srgb, truth_lin, masks)[0]


def clip_psnr_gain(frames_srgb: list[np.ndarray], truth_lin: np.ndarray, masks: np.ndarray) -> tuple[float, float]:
    """:func:`clip_psnr` and the clip's least-squares gain (linear light) it was taken after."""
    from relight.colour import decode_srgb8, linear_to_srgb

    pred = np.concatenate([decode_srgb8(f)[m] for f, m in zip(frames_srgb, masks, strict=True)]).astype(np.float64)
    want = np.concatenate([t[m] for t, m in zip(truth_lin, masks, strict=True)]).astype(np.float64)
    gain = float((pred * want).sum() / max(float((pred * pred).sum()), 1e-30))
    err = linear_to_srgb(np.clip(gain * pred, 0, 1)) - linear_to_srgb(np.clip(want, 0, 1))
    return float(10.0 * np.log10(1.0 / max(float((err.astype(np.float64) ** 2).mean()), 1e-30))), gain


def _filter(clip: Path, out: Path, bundle: Path, env: str, mode: str, region: str) -> dict:
    """``relight filter`` in a fresh process: (frames written, its report)."""
    dst = out / f"filtered_{mode}.mp4"
    report = out / f"report_{mode}"
    # The clip is a crop of a long-lens photo moved in the image plane: an orthographic camera
    # (the default focal length is a phone's whole frame, ~60 degrees across).
    from .clips import run_filter_process

    doc = run_filter_process(clip, dst, bundle, env, report, "--fixed-env", "--mode", mode, "--region", region)
    doc["output"] = str(dst)
    return doc


def evaluate_subject(folder: Path, out: Path, *, transfer: str, progress: bool = False,
                     region: str = DEFAULT_REGION) -> dict:
    """The real-face video benchmark for one subject (module docstring): PSNR of each mode, the
    unchanged input and the still prediction; frames with a face; the filter's light estimates."""
    import relight
    from relight.bench.accuracy_real import split_rti
    from relight.colour import encode_srgb8
    from relight.pipeline.capture import capture
    from relight.pipeline.capture_types import CaptureOptions
    from relight.video_read import read_frames

    out.mkdir(parents=True, exist_ok=True)
    train = out / "train"
    split_rti(folder, train)
    bundle = out / "face.bundle"
    if not bundle.exists():
        if progress:
            print(f"  capturing {folder.name} from its captured lights ...", flush=True)
        capture(train, bundle, CaptureOptions(transfer=transfer), images=True, progress=False)
    info = make_clip(folder, out, transfer)
    data = np.load(out / "truth.npz")
    truth, masks, motion = data["truth"].astype(np.float32), data["masks"], data["motion"]
    clip = out / "clip.mp4"
    frames_in = list(read_frames(clip))
    rows = {"input": {"psnr": clip_psnr(frames_in, truth, masks)}}
    env = "builtin:point:" + ",".join(f"{x:.6f}" for x in info["dir_b"])
    for mode in MODES:
        if progress:
            print(f"  relight filter --mode {mode} ...", flush=True)
        rep = _filter(clip, out, bundle, env, mode, region)
        frames = list(read_frames(Path(rep["output"])))
        rows[mode] = {"psnr": clip_psnr(frames, truth, masks), "faces": rep["faces"], "frames": rep["frames"],
                      "light": rep.get("live_light_summary", {})}
    b = relight.load_bundle(bundle)
    still = np.array(relight.Relighter(b, exact=True).relight_light(info["dir_b"]))  # what render --light gives
    h, w = still.shape[:2]
    fill = float((CANVAS_CODE / 255.0 + 0.055) / 1.055) ** 2.4
    moved = [encode_srgb8(place(still, m, fill=fill)) for m in motion]
    rows["still"] = {"psnr": clip_psnr(moved, truth, masks)}
    sheet = _sheet(frames_in, [list(read_frames(out / f"filtered_{m}.mp4")) for m in MODES], moved, truth)
    cv2.imwrite(str(out / "sheet.png"), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    return {"subject": folder.name, "clip": info, "modes": rows, "sheet": str(out / "sheet.png"),
            "face_share": {m: rows[m]["faces"] / max(rows[m]["frames"], 1) for m in MODES}}


def _sheet(inp, outs, still, truth) -> np.ndarray:
    """Before/after: rows are frames 0, 1/2, last; columns input, each mode, still, truth."""
    from relight.colour import encode_srgb8

    rows = []
    for i in (0, len(inp) // 2, len(inp) - 1):
        rows.append(np.concatenate([inp[i], *[o[i] for o in outs], still[i], encode_srgb8(truth[i])], axis=1))
    return np.concatenate(rows, axis=0)
