"""The decode matrix: one synthetic capture re-encoded as phones store video, each file captured
and measured against the synthetic truth - flash frames, registration, light directions,
normals, and the bundle relit against the truth's renders (what a user sees).

Run: ``.venv/bin/python -m tests.decode_matrix OUT [--size 640x360 --fps 25 --flash-hz 4
--duration 24 --seed 7]``; writes OUT/decode_matrix.md (the table docs/capture/decode_matrix.md
holds) and OUT/decode_matrix.json. The encoder is tests/phone_video.py (colour-science's curves:
the independent reference of relight's decoder).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from relight import load_bundle
from relight.pipeline.capture import capture
from relight.pipeline.evaluate import RELIT_ENVS, evaluate_capture
from relight.pipeline.synth.config import SynthConfig
from relight.pipeline.synth.studio import synthesize
from relight.video_colour import VideoColour

from .phone_video import encode_like_phone

#: (label, file name, codec, colour, display rotation, timestamps jittered by +-this many seconds,
#: lossless: the codec's lossless mode - what the decoding alone loses, apart from the second lossy
#: encode's own loss)
CASES = [
    ("H.264 8-bit sRGB (plain synth)", None, None, None, 0, 0.0, False),
    ("HEVC 10-bit HLG BT.2020, portrait, jittered (iPhone)", "iphone.mov", "libx265",
     VideoColour(matrix="bt2020", primaries="bt2020", transfer="hlg", bits=10), 90, 0.003, False),
    ("HEVC 10-bit HLG BT.2020, lossless", "hlg_lossless.mp4", "libx265",
     VideoColour(matrix="bt2020", primaries="bt2020", transfer="hlg", bits=10), 0, 0.0, True),
    ("HEVC 10-bit PQ BT.2020 (Android HDR10)", "hdr10.mp4", "libx265",
     VideoColour(matrix="bt2020", primaries="bt2020", transfer="pq", bits=10), 0, 0.0, False),
    ("HEVC 10-bit PQ BT.2020, lossless", "pq_lossless.mp4", "libx265",
     VideoColour(matrix="bt2020", primaries="bt2020", transfer="pq", bits=10), 0, 0.0, True),
    ("H.264 8-bit BT.709 curve, full range", "bt709full.mp4", "libx264",
     VideoColour(matrix="bt709", primaries="bt709", transfer="bt709", full_range=True), 0, 0.0, False),
    ("VP9 8-bit BT.601 sRGB", "vp9.webm", "libvpx-vp9", VideoColour(matrix="bt601", transfer="srgb"), 0, 0.0,
     False),
    ("AV1 10-bit Display P3 sRGB", "p3.mkv", "libsvtav1",
     VideoColour(matrix="bt709", primaries="p3", transfer="srgb", bits=10), 0, 0.0, False),
]


def run(out: Path, *, size=(640, 360), fps=25.0, flash_hz=4.0, duration=24.0, seed=7) -> list[dict]:
    out.mkdir(parents=True, exist_ok=True)
    synth_dir = out / "synth"
    if not (synth_dir / "truth" / "meta.json").exists():
        synthesize(synth_dir, SynthConfig(width=size[0], height=size[1], fps=fps, flash_hz=flash_hz, duration=duration,
                                          seed=seed), progress=False)
    src, truth = synth_dir / "capture.mp4", synth_dir / "truth"
    rows = []
    for label, name, codec, colour, rotation, jitter, lossless in CASES:
        video = src
        if name is not None:
            video = out / name
            if not video.exists():
                n = json.loads((truth / "meta.json").read_text())["frame_count"]
                times = None
                if jitter:
                    rng = np.random.default_rng(seed)
                    times = np.arange(n) / fps + rng.uniform(-jitter, jitter, n)
                    times -= times[0]
                encode_like_phone(src, video, colour, codec=codec, rotation=rotation, times=times, fps=fps,
                                  lossless=lossless)
        stem = video.stem if name is not None else "plain"
        t0 = time.perf_counter()
        res = capture(video, out / f"{stem}.bundle", report_dir=out / f"report-{stem}", progress=False)
        seconds = time.perf_counter() - t0
        m = evaluate_capture(res.report, load_bundle(out / f"{stem}.bundle"), truth)
        rows.append({"case": label, "file": video.name, "seconds": round(seconds, 1)} | m)
        print(_line(rows[-1], rows[0]), flush=True)
    (out / "decode_matrix.json").write_text(json.dumps(rows, indent=1))
    (out / "decode_matrix.md").write_text(table(rows, size, fps, flash_hz, duration, seed))
    return rows


def _line(r: dict, plain: dict) -> str:
    relit = " ".join(f"{r[f'relit_psnr_{e}']:.2f} ({r[f'relit_psnr_{e}'] - plain[f'relit_psnr_{e}']:+.2f})"
                     for e in RELIT_ENVS)
    return (f"{r['case']:55s} P/R {r['flash_precision']:.3f}/{r['flash_recall']:.3f} "
            f"reg {r['registration_rms_px']:.3f} px dir {r['light_dir_mean_deg']:.2f}/{r['light_dir_p95_deg']:.2f} "
            f"normals {r['normal_median_deg']:.2f} "
            f"relit {relit} dB ({r['seconds']:.0f} s)")


def table(rows, size, fps, flash_hz, duration, seed) -> str:
    envs = ", ".join(RELIT_ENVS)
    lines = ["# Decode matrix", "",
             f"One {size[0]}x{size[1]} {duration:g} s synthetic capture ({fps:g} fps, flash {flash_hz:g} Hz, seed "
             f"{seed}) re-encoded by `tests/phone_video.py` (the Y'CbCr codes computed from linear light with "
             "colour-science's curves, primaries and matrices - an implementation independent of relight's "
             "decoder - and the tags written), then `relight capture` on each file, measured against the synthetic "
             "truth (`pipeline/evaluate.py`): flash precision/recall, registration RMS, light directions "
             "mean/p95, normals median, and the bundle relit (default compact path) under "
             f"{envs} against the truth's renders - PSNR over the face after a sub-pixel alignment and one "
             "gain, in brackets the difference to the plain H.264 capture. The phone files are a second lossy "
             "encode (CRF 12) of the synthetic video; the lossless rows show what the decoding alone loses. Made by "
             "`python -m tests.decode_matrix OUT`.", "", "```"]
    lines += [_line(r, rows[0]) for r in rows]
    lines += ["```", ""]
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path)
    p.add_argument("--size", default="640x360")
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--flash-hz", type=float, default=4.0)
    p.add_argument("--duration", type=float, default=24.0)
    p.add_argument("--seed", type=int, default=7)
    a = p.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    run(a.out, size=(w, h), fps=a.fps, flash_hz=a.flash_hz, duration=a.duration, seed=a.seed)


if __name__ == "__main__":
    main()
