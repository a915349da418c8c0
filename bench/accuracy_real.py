"""The real-data half of ``relight bench accuracy``: photos nobody here made. Bundles from the
RTI dome's lights predict its held-out Test photos; each real face (Extended Yale B) predicts
its own held-out lights, against the baselines and the nearest captured photo. Also the RTI
set helpers other benches and tests use (shrink a set, hold lights out of it, list subjects)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .accuracy_bundles import build_variants, kb_per_px
from .accuracy_metrics import masked_ssim, unit_psnr
from .variants import BASELINES

#: Real faces (``../shared/data/faces-yale``): every FACE_HOLDOUT-th light of a subject (0, 6, 12,
#: ... in dirs.lp order) is held out and predicted from the rest. The Extended Yale B photos are
#: camera-linear (the data's README): decoded as such, compared sRGB-encoded.
FACE_HOLDOUT = 6
FACES_TRANSFER = "linear"
QUICK_FACES = ("yaleB01",)


def scaled_rti(folder: Path, out: Path, factor: int) -> Path:
    """A copy of an RTI image set (images, dirs.lp, mask.png, ambient) shrunk by ``factor`` (area
    average)."""
    import cv2

    from relight.pipeline.image_set import AMBIENT_NAMES, read_lp

    out.mkdir(parents=True, exist_ok=True)
    names = [n for n, _ in read_lp(folder / "dirs.lp")]
    for name in [*names, "mask.png", *AMBIENT_NAMES]:
        src = folder / name
        if not src.exists():
            continue
        img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{src}: not an image OpenCV reads")
        h, w = img.shape[:2]
        small = cv2.resize(img, (w // factor, h // factor), interpolation=cv2.INTER_AREA)
        jpeg = src.suffix.lower() in (".jpg", ".jpeg")
        cv2.imwrite(str(out / name), small, [cv2.IMWRITE_JPEG_QUALITY, 98] if jpeg else [])
    (out / "dirs.lp").write_text((folder / "dirs.lp").read_text())
    return out


def evaluate_dome(dome: Path, test: Path, out: Path, progress: bool, *, scale: int = 1) -> dict:
    """Bundles from Dome's lights predict Test's held-out photos (sRGB, no gain). ``scale`` > 1
    shrinks both sets first (``--quick``: the full set makes 1.1 GB bundles)."""
    import relight
    from relight.colour import linear_to_srgb
    from relight.imageio import read_image
    from relight.pipeline.image_set import read_lp

    if scale > 1:
        dome = scaled_rti(dome, out / "dome-small" / "Dome", scale)
        test = scaled_rti(test, out / "dome-small" / "Test", scale)
    bundles = build_variants(dome, out / "bundles" / "dome", images=True, progress=progress)
    lights_in = len(read_lp(dome / "dirs.lp"))
    held = [(d, read_image(test / name, linearize=False)[..., :3].astype(np.float32))
            for name, d in read_lp(test / "dirs.lp")]
    rows = {}
    for variant, info in bundles.items():
        b = relight.load_bundle(info["bundle"])
        rl = relight.Relighter(b, exact=True)
        dflt = relight.Relighter(b.default()) if b.recipe_stored else None
        mask = np.asarray(b.mask)
        ps, ss, pd = [], [], []
        for d, photo in held:
            pred = np.clip(linear_to_srgb(np.clip(np.array(rl.relight_light(d)), 0, None)), 0, 1)
            ps.append(unit_psnr(pred[mask], photo[mask]))
            ss.append(masked_ssim(pred, photo, mask))
            if dflt is not None:
                pred = np.clip(linear_to_srgb(np.clip(np.array(dflt.relight_light(d)), 0, None)), 0, 1)
                pd.append(unit_psnr(pred[mask], photo[mask]))
        rows[variant] = {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "psnr_per_light": ps,
                         "default_psnr": float(np.mean(pd)) if pd else None, "default_kb_per_px": kb_per_px(b)} | \
            {k: info[k] for k in ("capture_s", "maps_s", "bundle_mb")}
        del rl, dflt, b
        Path(info["bundle"]).unlink()  # ~1 GB each at full size; the size is recorded
    h, w = held[0][1].shape[:2]  # both sets share one size (a bundle renders the Dome frame)
    return {"lights_in": lights_in, "held_out": len(held), "variants": rows, "image_size": [w, h], "scale": scale}


def split_rti(folder: Path, out: Path, every: int = FACE_HOLDOUT) -> list[tuple[str, np.ndarray]]:
    """Write ``out``: an RTI set of ``folder``'s images without every ``every``-th light (0, every,
    2 every, ... in ``dirs.lp`` order; links to the files, its ``ambient.*`` and ``mask.png`` too).
    Returns the held-out (name, direction) pairs."""
    import os

    from relight.pipeline.image_set import AMBIENT_NAMES, read_lp

    entries = read_lp(folder / "dirs.lp")
    held = [e for i, e in enumerate(entries) if i % every == 0]
    train = [e for i, e in enumerate(entries) if i % every != 0]
    out.mkdir(parents=True, exist_ok=True)
    for name in [n for n, _ in train] + ["mask.png", *AMBIENT_NAMES]:
        src, dst = folder / name, out / name
        if src.exists() and not dst.exists():
            os.symlink(src.resolve(), dst)
    (out / "dirs.lp").write_text(f"{len(train)}\n" + "".join(f"{n} {d[0]:.6f} {d[1]:.6f} {d[2]:.6f}\n"
                                                              for n, d in train))
    return held


def evaluate_face(folder: Path, out: Path, progress: bool, *, variants=None, transfer: str = FACES_TRANSFER) -> dict:
    """A real face's held-out photos predicted by every variant and by the nearest captured photo.

    Every ``FACE_HOLDOUT``-th light of ``folder`` (an RTI set) is held out, the rest build the
    bundles; each held-out photo is predicted by ``relight_light`` (what ``render --light`` runs)
    plus the set's room-light frame (``render --ambient``), and both are compared sRGB-encoded
    (0-1, no gain) over the face (``mask.png``, else the whole crop): PSNR and SSIM."""
    import relight
    from relight.colour import linear_to_srgb
    from relight.pipeline.image_set import read_lp, read_set_image

    train = out / "train" / folder.name
    held = split_rti(folder, train)
    bundles = build_variants(train, out / "bundles" / folder.name, images=True, variants=variants,
                             progress=progress, transfer=transfer)
    photos = [(d, linear_to_srgb(read_set_image(folder / name, transfer)[0])) for name, d in held]
    shots = [(d, read_set_image(folder / name, transfer)[0]) for name, d in read_lp(train / "dirs.lp")]
    rows: dict = {}
    mask = None
    for variant, info in bundles.items():
        b = relight.load_bundle(info["bundle"])
        rl = relight.Relighter(b, exact=True)
        dflt = relight.Relighter(b.default()) if b.recipe_stored else None
        mask = np.asarray(b.mask)
        room = b.ambient_frame()
        ps, ss, pd = [], [], []
        for d, photo in photos:
            pred = np.clip(linear_to_srgb(np.clip(np.array(rl.relight_light(d)) + room, 0, None)), 0, 1)
            ps.append(unit_psnr(pred[mask], photo[mask]))
            ss.append(masked_ssim(pred, photo, mask))
            if dflt is not None:
                pred = np.clip(linear_to_srgb(np.clip(np.array(dflt.relight_light(d)) + room, 0, None)), 0, 1)
                pd.append(unit_psnr(pred[mask], photo[mask]))
        rows[variant] = {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "psnr_per_light": ps,
                         "default_psnr": float(np.mean(pd)) if pd else None, "default_kb_per_px": kb_per_px(b)} | \
            {k: info[k] for k in ("capture_s", "maps_s", "bundle_mb")}
        del rl, dflt, b
        Path(info["bundle"]).unlink()
    ps, ss = [], []
    for d, photo in photos:  # the nearest captured photo, as it is
        near = linear_to_srgb(shots[int(np.argmax([float(np.dot(d, t)) for t, _ in shots]))][1])
        ps.append(unit_psnr(near[mask], photo[mask]))
        ss.append(masked_ssim(near, photo, mask))
    rows["nearest"] = {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "psnr_per_light": ps,
                       "capture_s": 0.0, "maps_s": 0.0, "bundle_mb": 0.0}
    others = [n for n in (*BASELINES, "nearest") if n in rows]
    best = max(others, key=lambda n: rows[n]["psnr"])
    return {"subject": folder.name, "lights_in": len(shots), "held_out": [n for n, _ in held],
            "held_out_dirs": [[round(float(x), 6) for x in d] for _, d in held], "transfer": transfer,
            "image_size": [int(mask.shape[1]), int(mask.shape[0])], "variants": rows, "best_other": best,
            "margin_db": rows["full"]["psnr"] - rows[best]["psnr"] if "full" in rows else None}


def face_subjects(faces: Path | None) -> list[Path]:
    """The subject folders (each an RTI set with ``dirs.lp``) of a faces folder, sorted."""
    if faces is None or not Path(faces).is_dir():
        return []
    return sorted(p for p in Path(faces).iterdir() if (p / "dirs.lp").exists())
