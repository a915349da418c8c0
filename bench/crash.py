"""``relight bench crash``: writers killed with SIGKILL at random moments.

Three writers, each run as a user runs it (a real process, killed with ``kill -9``: no handler,
no ``finally``, no flush) while a previous result sits at the target path:

* ``relight capture --images`` of a real face (Yale B01, shrunk) -> ``face.bundle``;
* ``relight filter`` of a clip of real face photos -> ``relit.mp4``;
* ``relight-serve`` taking an environment upload (``PUT /v1/environment``, a 2048x1024 .hdr),
  killed during the upload or its validation.

Kill times are drawn at random over a measured uninterrupted run, half of them in its last
fifth (where the writing happens). After each kill the target must be the previous file, byte
for byte, or a new file that is whole (a bundle that loads with every checksum and check, a
video whose every frame decodes and whose frame count is the input's); anything else is
counted as damaged. Temporaries a killed writer left are counted, and must be gone after the
next uninterrupted run (the writers remove those of dead processes). Figures: kills, outcomes,
temporaries left and cleaned, damaged = 0.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

#: Kills per writer: CI's bounded pass, the bench's default.
QUICK_KILLS = 4
DEFAULT_KILLS = 25


def _relight(*args: str) -> list[str]:
    return [sys.executable, "-m", "relight", *args]


def _run_killed(cmd: list[str], at: float, env: dict | None = None) -> bool:
    """Run ``cmd``; SIGKILL its whole process group ``at`` seconds in. True when it was killed
    (False: it finished first)."""
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                         env=env)
    try:
        p.wait(timeout=at)
        return False
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        return True


def _timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return time.perf_counter() - t0


def _kill_times(rng, n: int, full: float) -> list[float]:
    """Half uniform over the run, half in its last fifth (the write), a few past its end."""
    early = rng.uniform(0.05, 1.0, n - n // 2) * full
    late = rng.uniform(0.8, 1.05, n // 2) * full
    return sorted(np.concatenate([early, late]).tolist())


def _temps(target: Path) -> set[Path]:
    """The temporaries of writers of ``target`` in its folder (``.{stem}.{pid}.{random}.tmp...``;
    a folder output's ``.{name}.`` ones start the same way)."""
    return {p for p in target.parent.iterdir() if p.name.startswith(f".{target.stem}.") and ".tmp" in p.name}


def _outcome(path: Path, previous: bytes, whole) -> str:
    if not path.exists():
        return "absent"
    data = path.read_bytes()
    if data == previous:
        return "previous"
    try:
        whole(path)
    except Exception:  # noqa: BLE001 - any failure to read it back is damage
        return "damaged"
    return "new"


def _bundle_whole(path: Path) -> None:
    from relight import load_bundle

    from .fuzz_targets import use_bundle

    use_bundle(load_bundle(path))


def _video_whole(frames: int):
    def check(path: Path) -> None:
        from relight.video_read import probe_video, read_frames

        probe_video(path)
        n = sum(1 for _ in read_frames(path))
        if n != frames:
            raise ValueError(f"{n} frames, the input has {frames}")
    return check


def _writer(name: str, cmd: list[str], target: Path, whole, kills: int, rng, progress: bool) -> dict:
    """Kill ``cmd`` ``kills`` times with ``target`` in place; then one whole run."""
    folder = target.parent
    full = _timed(cmd)  # also the previous result
    outcomes = {"previous": 0, "new": 0, "absent": 0, "damaged": 0}
    killed = left = 0
    for i, at in enumerate(_kill_times(rng, kills, full)):
        previous = target.read_bytes()
        before = _temps(target)
        killed += _run_killed(cmd, at)
        after = _temps(target)
        left += len(after - before)
        outcome = _outcome(target, previous, whole)
        outcomes[outcome] += 1
        if progress:
            print(f"  {name} kill {i + 1}/{kills} at {at:.2f} s of {full:.2f}: {outcome}, "
                  f"{len(after)} temporaries", flush=True)
        if outcome in ("absent", "damaged"):
            (folder / f"damaged-{i}{target.suffix}").write_bytes(target.read_bytes() if target.exists() else b"")
            _timed(cmd)  # the next kill needs a previous result
    stale = len(_temps(target))
    _timed(cmd)  # an uninterrupted run: it removes the dead writers' temporaries
    remaining = len(_temps(target))
    return {"writer": name, "kills": kills, "killed": killed, "run_s": full, **outcomes,
            "damaged_total": outcomes["damaged"] + outcomes["absent"], "temporaries_left": left,
            "stale_before_next_run": stale, "temporaries_after_next_run": remaining}


def _upload(kills: int, rng, work: Path, bundle: Path, progress: bool) -> dict:
    """relight-serve killed while it takes an environment upload; the next start cleans up."""
    import cv2
    import httpx

    from relight import load_environment
    from relight.imageio import write_image

    from .server import free_port, wait_ready

    env = load_environment(_probe_source())
    big = write_image(work / "upload.hdr", cv2.resize(env, (2048, 1024), interpolation=cv2.INTER_LINEAR))
    body = big.read_bytes()
    tmp = work / "server-tmp"
    tmp.mkdir(exist_ok=True)
    environ = {**os.environ, "TMPDIR": str(tmp)}

    def start():
        port = free_port()
        p = subprocess.Popen([*_serve_cmd(), str(bundle), "--port", str(port)], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True, env=environ)
        base = f"http://127.0.0.1:{port}"
        if not wait_ready(base, 60, alive=lambda: p.poll() is None):
            raise RuntimeError("relight-serve did not start")
        return p, base

    def put(base):
        return httpx.put(f"{base}/v1/environment", content=body, headers={"content-type": "image/vnd.radiance"},
                         timeout=60)

    p, base = start()
    t0 = time.perf_counter()
    r = put(base)
    full = time.perf_counter() - t0
    if r.status_code != 200:
        raise RuntimeError(f"the upload was refused: {r.status_code} {r.text[:200]}")
    left = served = 0
    for i, at in enumerate(sorted(rng.uniform(0.0, 1.1, kills) * full)):
        th = threading.Thread(target=lambda b=base: _quiet(put, b), daemon=True)
        th.start()
        time.sleep(at)
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        th.join(10)
        dead = p.pid
        stale = [d for d in tmp.iterdir() if d.name.startswith(f"relight-env-{dead}-")]
        left += len(stale)
        p, base = start()  # the next start
        stale_after = [d for d in tmp.iterdir() if d.name.startswith(f"relight-env-{dead}-")]
        ok = httpx.get(f"{base}/v1/environment", timeout=10).status_code == 200
        served += ok and not stale_after
        if progress:
            print(f"  upload kill {i + 1}/{kills} at {at:.3f} s of {full:.3f}: {len(stale)} upload folders left, "
                  f"{len(stale_after)} after the restart, serving {'yes' if ok else 'NO'}", flush=True)
    os.killpg(p.pid, signal.SIGTERM)
    p.wait(30)
    return {"writer": "environment upload", "kills": kills, "killed": kills, "run_s": full,
            "temporaries_left": left, "restarts_clean_and_serving": served,
            "damaged_total": kills - served}


def _quiet(fn, *args):
    try:
        fn(*args)
    except Exception:  # noqa: BLE001 - the server was killed under the request
        pass


def _serve_cmd() -> list[str]:
    return [sys.executable, "-c", "from relight.cli import serve_main; raise SystemExit(serve_main())"]


def _probe_source():
    from .fuzz import shared_data

    shared = shared_data()
    return shared / "envmaps" / "uffizi.hdr" if shared is not None else "builtin:window"


def _face_inputs(work: Path, progress: bool) -> tuple[Path, Path, int]:
    """(image set, clip, its frame count): Yale B01 shrunk 4x for the capture, a 3 s clip of its
    photos at half size for the filter (the synthetic studio's without ../shared)."""
    import cv2

    from relight.video_write import VideoWriter

    from .fuzz import shared_data
    from .fuzz_seeds import real_face_frames

    shared = shared_data()
    images = work / "yale4"
    if not images.exists():
        if shared is not None:
            from .accuracy_real import scaled_rti
            scaled_rti(shared / "faces-yale" / "yaleB01", images, 4)
        else:
            raise RuntimeError("relight bench crash needs ../shared/data (the real faces)")
    clip = work / "clip.mp4"
    frames = real_face_frames(10, (320, 240))
    n = 90
    if not clip.exists():
        with VideoWriter(clip, 30, (320, 240)) as wr:
            for i in range(n):
                wr.write(cv2.GaussianBlur(frames[(i // 9) % len(frames)], (3, 3), 0))
    return images, clip, n


def run(out: Path, *, kills: int = DEFAULT_KILLS, seed: int = 0, progress: bool = True,
        writers=("capture", "filter", "upload")) -> dict:
    from relight.imageio import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    work = out / "work"
    work.mkdir(exist_ok=True)
    rng = np.random.default_rng(seed)
    images, clip, n = _face_inputs(work, progress)
    bundle = work / "face.bundle"
    rows = []
    if "capture" in writers or not bundle.exists():
        if progress:
            print("capture ...", flush=True)
        row = _writer("capture", _relight("capture", "--images", str(images), "-o", str(bundle), "--quiet"),
                      bundle, _bundle_whole, kills, rng, progress)
        if "capture" in writers:
            rows.append(row)
    if "filter" in writers:
        if progress:
            print("filter ...", flush=True)
        relit = work / "relit.mp4"
        rows.append(_writer("filter", _relight("filter", "--bundle", str(bundle), "--env", "builtin:sunset",
                                               "--quiet", str(clip), str(relit)),
                            relit, _video_whole(n), kills, rng, progress))
    if "upload" in writers:
        if progress:
            print("environment upload ...", flush=True)
        rows.append(_upload(kills, rng, work, bundle, progress))
    doc = {"kills_per_writer": kills, "seed": seed, "writers": rows}
    with atomic_path(out / "bench.json") as tmp:
        tmp.write_text(json.dumps(doc, indent=2))
    return doc


def table(doc: dict) -> str:
    lines = ["| writer | kills | previous intact | new, whole | damaged or lost | temporaries left | "
             "after the next run |", "|---|---|---|---|---|---|---|"]
    for r in doc["writers"]:
        if r["writer"] == "environment upload":
            lines.append(f"| {r['writer']} | {r['kills']} | - | - | {r['damaged_total']} | {r['temporaries_left']} "
                         f"upload folders | 0 left in {r['restarts_clean_and_serving']} of {r['kills']} restarts, "
                         "serving |")
        else:
            lines.append(f"| {r['writer']} | {r['killed']} (+{r['kills'] - r['killed']} finished first) | "
                         f"{r['previous']} | {r['new']} | {r['damaged_total']} | {r['temporaries_left']} | "
                         f"{r['temporaries_after_next_run']} |")
    return "\n".join(lines)

