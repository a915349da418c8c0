"""``relight bench fuzz``: every reader of hostile input, fed mutated real files (Hypothesis).

Targets (each the function a user's file or a client's request reaches first, then what the
product does with what it returned):

* ``bundle`` - :func:`relight.load_bundle`, then every accessor the relighter and the service
  read (background, masks, frame index, room light, recipe, maps of a few pixels). Mutations
  of the raw bytes, and of the JSON header with its checksums made right again (a crafted
  file, not only a damaged one).
* ``lp`` - the RTI light-position parser (:func:`relight.pipeline.capture.read_lp`).
* ``envmap`` - an environment upload (``PUT /v1/environment``), i.e. the file loader behind it
  (.hdr / .exr / .png headers and payloads through OpenImageIO).
* ``frame`` - the image decoder behind ``POST /v1/relight`` (PNG / JPEG).
* ``control`` - the websocket's (and the WebRTC data channel's) JSON control messages.
* ``video`` - the video prober and the first frames' decode (MP4 H.264, MOV HEVC 10-bit
  portrait with HDR tags, WebM VP9).

Seeds are real files: ``../shared/data`` (the Yale faces, the RTI dome's photos and light
positions, the HDR light probes) and files the product makes from them (a bundle captured from
a real face, clips of real face photos); without ``../shared`` the synthetic studio's. A run
counts the inputs tried per target, the outcomes (accepted, refused with our error), crashes
(any other exception: Hypothesis shrinks it and the report prints the smallest input) and the
largest memory one input made us allocate (``tracemalloc`` peak: NumPy's buffers included;
the peak resident set of the target's process as well, which counts native buffers too).

The parts: :mod:`~relight.bench.fuzz_targets` (the readers and what they do with their
input), :mod:`~relight.bench.fuzz_seeds` (the seed files), :mod:`~relight.bench.fuzz_mutations`
(the byte edits); this module runs Hypothesis on each target, in its own process, and writes
``bench.json``.
"""

from __future__ import annotations

import json
import resource
import time
import tracemalloc
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from .fuzz_mutations import apply_mutations, mutations
from .fuzz_seeds import shared_data
from .fuzz_targets import TARGETS, Scratch, expected_refusal

#: Inputs per target: CI's bounded pass, the bench's default; ``--examples`` sets any other.
QUICK_EXAMPLES = 40
DEFAULT_EXAMPLES = 1500


@dataclass
class Result:
    target: str
    what: str
    caps: str
    inputs: int = 0
    accepted: int = 0
    refused: int = 0
    crashes: int = 0
    crash: str = ""
    seconds: float = 0.0
    peak_traced_mb: float = 0.0
    peak_rss_mb: float = 0.0
    seeds: int = 0
    refusals: dict = field(default_factory=dict)
    # Largest rise of the process's peak resident set on one input (MB): a lower bound of what
    # that input made native code (OpenImageIO, FFmpeg, PoCL) allocate and touch.
    rss_rise_mb: float = 0.0


def fuzz_target(name: str, work: Path, examples: int, seed: int = 0, *, raise_crash: bool = False) -> Result:
    """Fuzz one target with ``examples`` Hypothesis examples; a crash is shrunk and recorded (or
    raised with ``raise_crash``, for tests)."""
    from hypothesis import HealthCheck, Phase, Verbosity, given, settings
    from hypothesis import seed as hseed
    from hypothesis import strategies as st
    from hypothesis.errors import HypothesisWarning

    work.mkdir(parents=True, exist_ok=True)
    scratch = Scratch(work)
    try:
        target = TARGETS[name](work, scratch)
        res = Result(target=name, what=target.what, caps=target.caps, seeds=len(target.seeds))
        seeds = target.seeds
        byte_inputs = st.tuples(st.sampled_from(seeds), mutations(st)).map(
            lambda se: apply_mutations(se[0], se[1], seeds))
        inputs = byte_inputs | target.structured(st) if target.structured else byte_inputs
        peak = [0]
        rss_high = [resource.getrusage(resource.RUSAGE_SELF).ru_maxrss]

        crash_input = [None]

        def one(data: bytes) -> None:
            res.inputs += 1
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
            try:
                target.run(data)
                res.accepted += 1
            except Exception as exc:  # noqa: BLE001 - sorting refusals from crashes is the point
                if not expected_refusal(exc):
                    crash_input[0] = data  # the last failing input Hypothesis tries is its shrunk one
                    raise
                res.refused += 1
                kind = type(exc).__name__
                res.refusals[kind] = res.refusals.get(kind, 0) + 1
            finally:
                peak[0] = max(peak[0], tracemalloc.get_traced_memory()[1] - base)
                rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                if rss - rss_high[0] > res.rss_rise_mb * 1024:  # the largest rise of the high-water mark
                    res.rss_rise_mb = (rss - rss_high[0]) / 1024
                    (work / f"rss-{name}.bin").write_bytes(data)
                rss_high[0] = max(rss_high[0], rss)

        test = settings(max_examples=examples, deadline=None, database=None, derandomize=False,
                        suppress_health_check=list(HealthCheck), phases=[Phase.generate, Phase.shrink],
                        print_blob=False, verbosity=Verbosity.quiet)(given(inputs)(one))
        test = hseed(seed)(test)
        warnings.filterwarnings("ignore", category=HypothesisWarning)  # "overly large repr" of file-sized inputs
        started = tracemalloc.is_tracing()
        if not started:
            tracemalloc.start()
        t0 = time.perf_counter()
        try:
            test()
        except Exception as exc:  # noqa: BLE001 - the shrunk crash, reported
            res.crashes += 1
            res.crash = f"{type(exc).__name__}: {exc}"[:2000]
            if crash_input[0] is not None:
                kept = work / f"crash-{name}.bin"
                kept.write_bytes(crash_input[0])
                res.crash += f" (input kept in {kept})"
            if raise_crash:
                raise
        finally:
            res.seconds = time.perf_counter() - t0
            if not started:
                tracemalloc.stop()
        res.peak_traced_mb = peak[0] / 2 ** 20
        res.peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        return res
    finally:
        scratch.close()


def _child(name: str, work: str, examples: int, seed: int, queue) -> None:
    try:
        queue.put(fuzz_target(name, Path(work), examples, seed).__dict__)
    except BaseException as exc:  # the child's own failure (seeds, imports): reported as a crash
        queue.put({"target": name, "what": "", "caps": "", "crashes": 1, "crash": f"{type(exc).__name__}: {exc}"})


def run(out: Path, *, targets=None, examples: int = DEFAULT_EXAMPLES, seed: int = 0, progress: bool = True) -> dict:
    """Fuzz each target in its own process (its peak RSS its own); write ``bench.json``."""
    import multiprocessing as mp

    from relight.imageio import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    names = list(targets or TARGETS)
    ctx = mp.get_context("spawn")
    rows = []
    for name in names:
        if progress:
            print(f"fuzz {name}: {examples} inputs ...", flush=True)
        q = ctx.Queue()
        p = ctx.Process(target=_child, args=(name, str(out / "seeds"), examples, seed, q))
        p.start()
        try:
            row = q.get(timeout=max(600.0, examples * 2.0))
        except Exception:  # noqa: BLE001 - the child died without a word: a crash of the process
            row = {"target": name, "what": "", "caps": "", "crashes": 1,
                   "crash": f"the process died (exit code {p.exitcode}); the input it died on is under "
                            f"{out / 'seeds'}/scratch-*"}
        p.join(30)
        if p.exitcode not in (0, None) and not row.get("crash"):
            row.update(crashes=1, crash=f"the process exited with code {p.exitcode}")
        rows.append(row)
        if progress:
            print(f"  {row.get('inputs', 0)} inputs, {row.get('crashes', 0)} crashes, "
                  f"{row.get('seconds', 0):.1f} s", flush=True)
    doc = {"examples": examples, "seed": seed, "real_seeds": shared_data() is not None, "targets": rows}
    with atomic_path(out / "bench.json") as tmp:
        tmp.write_text(json.dumps(doc, indent=2))
    return doc


def table(doc: dict) -> str:
    lines = ["| target | inputs | accepted | refused (our error / 4xx) | crashes | largest allocation of one input "
             "(traced / RSS rise) | time | caps |", "|---|---|---|---|---|---|---|---|"]
    for r in doc["targets"]:
        lines.append(f"| {r['target']} | {r.get('inputs', 0)} | {r.get('accepted', 0)} | {r.get('refused', 0)} | "
                     f"{r.get('crashes', 0)} | {r.get('peak_traced_mb', 0):.1f} / {r.get('rss_rise_mb', 0):.0f} MB | "
                     f"{r.get('seconds', 0):.0f} s | {r.get('caps', '')} |")
    crashes = [r for r in doc["targets"] if r.get("crashes")]
    for r in crashes:
        lines.append(f"\ncrash in {r['target']}: {r['crash']}")
    return "\n".join(lines)
