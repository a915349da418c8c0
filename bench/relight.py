"""``relight bench relight``: error against run time of the relighting engine.

One synthetic 960x540 capture (cached) is captured into a bundle; then, in one run and side by
side: the exact path and the compact path at several tolerances on PoCL, their NumPy twins,
and what a user would write instead (the same product with NumPy/BLAS on float32 data), for a
smooth sky with a small sun, a studio, a small sun alone, front-only versions, and a single
point light. Every timing is a median over many calls after warm-up, with the head rotation
changing on every call. Figures: relative L2 error against the exact path, PSNR against the
synthetic truth (after one exposure gain), milliseconds per relight (whole call, and the
per-pixel stage alone) scaled to 100k face pixels, and bytes moved per relight over time as a
fraction of this machine's memory read bandwidth, measured in the same run.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from relight.kernels.texel_lights import split_direct

TOLERANCES = (0.05, 0.02, 0.01, 0.005, 0.002)
#: Timing: rounds x (pause, warm-up calls, timed calls) per function, functions in turn.
ROUNDS = 5
PER_ROUND = 8
WARMUP = 2
#: Seconds between two functions' blocks: OpenBLAS's and PoCL's worker threads spin for a while
#: after their last call and would steal the 2 cores from the next function (measured: the
#: compact kernel 2x slower when timed right after a BLAS call).
PAUSE = 0.1
#: The speed goal drawn on the error-vs-time plot (issue 15): relative L2 error against the exact
#: path at or below GOAL_ERROR in at most GOAL_MS_PER_100K ms per call per 100k face pixels.
GOAL_ERROR = 0.01
GOAL_MS_PER_100K = 1.0


def _blocked_ms(fns: dict, rounds=ROUNDS, per=PER_ROUND, warmup=WARMUP, pause=PAUSE) -> dict:
    """Median ms of several functions, timed in blocks that take turns (A B C A B C ...): on a
    shared machine whose speed drifts, taking turns keeps the comparison fair; the pause and the
    warm-up calls before each block keep one library's idle threads out of the next one's time."""
    ts = {k: [] for k in fns}
    i = 0
    for _ in range(rounds):
        for k, f in fns.items():
            time.sleep(pause)
            for _ in range(warmup):
                f(i)
                i += 1
            for _ in range(per):
                t = time.perf_counter()
                f(i)
                ts[k].append(time.perf_counter() - t)
                i += 1
    return {k: float(np.median(v) * 1000.0) for k, v in ts.items()}


def _median_ms(fn, n=PER_ROUND * ROUNDS, warmup=WARMUP) -> float:
    return _blocked_ms({"f": fn}, rounds=1, per=n, warmup=warmup, pause=0.0)["f"]


class ReadProbe:
    """This machine's memory read bandwidth, measured the way the kernels read: an OpenCL kernel
    on the same device streaming a 256 MB float32 buffer (far larger than the caches) with 64-byte
    vector loads, each work item its own contiguous chunk. ``__call__`` runs it once."""

    MB = 256

    def __init__(self, mb: int = MB):
        import pyopencl as cl

        from relight.kernels.runtime import get_runtime

        self.rt = get_runtime()
        src = """__kernel void rd(__global const float16 *x, int per, __global float *out) {
            int g = get_global_id(0);
            __global const float16 *mine = x + (size_t)g * per;
            float16 a = (float16)(0.0f), b = (float16)(0.0f);
            for (int i = 0; i < per; i += 2) { a += mine[i]; b += mine[i + 1]; }
            a += b;
            out[g] = a.s0 + a.s5 + a.sa + a.sf; }"""
        self.kernel = cl.Kernel(cl.Program(self.rt.context, src).build(), "rd")
        from relight.kernels.runtime import aligned_zeros

        self.items = 1024
        self.data = aligned_zeros((mb * (1 << 20) // 4,), np.float32)
        self.data[:] = 1.0
        mf = cl.mem_flags
        self.buf = cl.Buffer(self.rt.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=self.data)
        self.out = cl.Buffer(self.rt.context, mf.WRITE_ONLY, self.items * 4)
        self.nbytes = self.data.nbytes

    def __call__(self, i=0):
        per = self.data.size // 16 // self.items
        self.kernel(self.rt.queue, (self.items,), (16,), self.buf, np.int32(per), self.out)
        self.rt.queue.finish()

    def gbps(self, ms: float) -> float:
        return self.nbytes / ms / 1e6


def measure_bandwidth(probe: ReadProbe) -> dict:
    """Memory bandwidth of this machine (GB/s): the OpenCL read probe and a NumPy copy (read + write)."""
    a = np.ones(probe.data.size, dtype=np.float32)
    b = np.empty_like(a)
    t = _blocked_ms({"copy": lambda i: np.copyto(b, a), "read": probe}, rounds=3, per=3, warmup=1)
    return {"numpy_copy_gbps": 2 * a.nbytes / t["copy"] / 1e6, "opencl_read_gbps": probe.gbps(t["read"])}


def frontal_environment(env: np.ndarray) -> np.ndarray:
    """The environment kept only well inside a frontal capture's hull (within 55 degrees of the
    camera axis, elevation -25..55 degrees), black elsewhere."""
    from relight.directions import equirect_directions

    h, w = env.shape[:2]
    d = equirect_directions(w, h)
    el = np.degrees(np.arcsin(np.clip(d[..., 1], -1, 1)))
    keep = (d[..., 2] > np.cos(np.radians(55))) & (el > -25) & (el < 55)
    return (env * keep[..., None]).astype(np.float32)


def _scenario(out: Path, quick: bool, progress: bool):
    """(bundle path, truth folder, {name: env source}) for the benchmark capture (cached)."""
    from relight.envmap import load_environment
    from relight.imageio import write_image
    from relight.pipeline.synth.config import SynthConfig
    from relight.pipeline.synth.studio import cached_synthesis

    out.mkdir(parents=True, exist_ok=True)
    front_studio = out / "front_studio.exr"
    front_sky = out / "front_sky.exr"
    if not front_studio.exists():
        write_image(front_studio, frontal_environment(load_environment("builtin:studio")))
        write_image(front_sky, frontal_environment(load_environment("builtin:sunset")))
    envs = {"sky (sunset)": "builtin:sunset", "studio": "builtin:studio", "small sun": "builtin:point:0.5,0.3,0.8",
            "front studio": str(front_studio), "front sky": str(front_sky)}
    size = (480, 270) if quick else (960, 540)
    cfg = SynthConfig(width=size[0], height=size[1], duration=10.0 if quick else 60.0, seed=0,
                      truth_envs=tuple(envs.values()))
    cap = cached_synthesis(out, cfg, label=f"a {size[0]}x{size[1]} capture", progress=progress)
    bundle = out / f"{cap.name.removeprefix('synth-')}.bundle"
    if not bundle.exists():
        from relight.pipeline.capture import capture

        if progress:
            print("capturing it ...", flush=True)
        capture(cap / "capture.mp4", bundle, progress=progress)
    return bundle, cap / "truth", envs


def _start_time(bundle: Path) -> dict:
    """Seconds to load the bundle and build the Relighter in a fresh process (twice: cold, warm)."""
    code = (f"import time; t=time.perf_counter(); import relight; b=relight.load_bundle({str(bundle)!r}); "
            "r=relight.Relighter(b); print(time.perf_counter()-t)")
    out = []
    for _ in range(2):
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        out.append(float(p.stdout.strip().splitlines()[-1]))
    return {"first_s": out[0], "warm_s": out[1]}


def run(out: Path, quick: bool = False, progress: bool = True) -> dict:
    import relight
    from relight.directions import rotation_matrix
    from relight.imageio import read_image
    from relight.kernels import texel_lights
    from relight.kernels.relighter import Relighter

    bundle_path, truth_dir, envs = _scenario(Path(out), quick, progress)
    bundle = relight.load_bundle(bundle_path)
    meta = json.loads((truth_dir / "meta.json").read_text())
    p = int(bundle.pixels.size)
    per100k = 1e5 / p
    mask = bundle.mask & (read_image(truth_dir / "mask.png")[..., 0] > 0.5)
    probe = ReadProbe(64 if quick else ReadProbe.MB)
    bw = measure_bandwidth(probe)
    start = _start_time(bundle_path)
    rots = [rotation_matrix(8 * np.sin(i / 7), 4 * np.sin(i / 5), 2 * np.sin(i / 11)) for i in range(4000)]
    exact = Relighter(bundle, exact=True)
    compacts = {t: Relighter(bundle, tolerance=t) for t in TOLERANCES}
    truth_of = {}
    for name, src in envs.items():
        stem = relight.envmap.environment_stem(src)
        if stem in meta["files"]["relit"]:
            truth_of[name] = read_image(truth_dir.parent / meta["files"]["relit"][stem])
    rows = []
    for name, src in envs.items():
        if progress:
            print(f"timing {name} ...", flush=True)
        rows.append(_bench_env(name, relight.load_environment(src), exact, compacts, rots, mask, truth_of.get(name),
                               p, probe, quick))
    # A single point light: the maps' own texels, no environment.
    light = np.array([0.5, 0.3, 0.8])
    lp = texel_lights.point_light(light, bundle.map_size, np.asarray(bundle.map_texels))
    pl = _blocked_ms({"light": lambda i: exact.relight_light(light + 0.01 * np.sin(i) * np.array([1, 0, 0])),
                      "exact": lambda i: exact.relight_texels(lp)})
    pl_bytes = 4 * 3 * p * 2 + p * 16
    doc = {"pixels": p, "frame": list(bundle.frame_size), "map_size": list(bundle.map_size),
           "texels": int(bundle.map_texels.size), "bandwidth": bw, "start": start, "envs": rows,
           "point_light": {"ms_call": pl["light"], "ms_call_per_100k": pl["light"] * per100k, "bytes": pl_bytes,
                           "ms_via_full_exact_path": pl["exact"]},
           "device": exact.rt.description,
           "timing": {"rounds": ROUNDS, "per_round": PER_ROUND, "warmup": WARMUP, "pause_s": PAUSE}}
    out = Path(out)
    (out / "bench.json").write_text(json.dumps(doc, indent=1))
    _plot(doc, out / "relight_error_vs_time.png")
    return doc


def _psnr(pred, truth, mask):
    """PSNR (dB, peak = the truth's maximum) after one exposure gain, and the gain."""
    a, b = pred[mask], truth[mask]
    g = float((a * b).sum() / max((a * a).sum(), 1e-30))
    mse = float(((g * a - b) ** 2).mean())
    return 10 * np.log10(float(b.max()) ** 2 / max(mse, 1e-30)), g


def _bench_env(name, env, exact, compacts, rots, mask, truth, p, probe, quick) -> dict:
    """Every path on one environment."""
    from relight.kernels.relight_inputs import frozen
    from relight.kernels.relight_packing import LANES, exact_light_blocks

    per100k = 1e5 / p
    env = frozen(env)  # as the frame path passes it (no hashing per call); the calls fill `out` in place
    out = np.zeros_like(exact.frame)
    e_img = exact.relight(env)
    row = {"env": name, "paths": []}
    lp = exact.texel_light(env, rots[3])
    lp_t = lp / exact.sample_scale  # relight_texels takes flash units (texel_light's are scaled)
    # The exact kernel and the bandwidth probe take turns: the fraction compares like with like.
    t = _blocked_ms({"call": lambda i: exact.relight(env, rots[i], out=out),
                     "kernel": lambda i: exact.relight_texels(lp_t),
                     "probe": probe}, rounds=3 if quick else 4, per=3, warmup=1)
    e_ms, e_kernel = t["call"], t["kernel"]
    _, lit = exact_light_blocks(lp, exact.t_exact)
    e_bytes = p * 3 * lit.size * LANES * 2 + p * 16  # maps' lit blocks + frame index and RGB out
    e_np = _median_ms(lambda i: exact.relight_numpy(env, rots[i], exact=True), n=3, warmup=1)
    gbps = e_bytes / e_kernel / 1e6
    ent = {"path": "exact", "rank": None, "rel_l2_vs_exact": 0.0, "ms_call": e_ms, "ms_kernel": e_kernel,
           "ms_call_per_100k": e_ms * per100k, "ms_kernel_per_100k": e_kernel * per100k, "ms_numpy_twin": e_np,
           "bytes": e_bytes, "gbps": gbps, "read_gbps_same_time": probe.gbps(t["probe"]),
           "bw_fraction": gbps / probe.gbps(t["probe"])}
    if truth is not None:
        ent["psnr_vs_truth"], ent["gain"] = _psnr(e_img, truth, mask)
    row["paths"].append(ent)
    for tol, rl in compacts.items():
        if not rl.exact:
            row["paths"].append(_bench_compact(tol, rl, env, e_img, rots, mask, truth, p, probe, quick))
    return row


def _bench_compact(tol, rl, env, e_img, rots, mask, truth, p, probe, quick) -> dict:
    from relight.kernels.relight_inputs import frozen
    from relight.kernels.relight_packing import LANES
    from relight.numerics import read_halves

    per100k = 1e5 / p
    env = frozen(env)
    out = np.zeros_like(rl.frame)
    c_img = rl.relight(env)
    rel = float(np.linalg.norm(c_img[mask] - e_img[mask]) / np.linalg.norm(e_img[mask]))
    r_img_c = rl.relight(env, rots[7])
    # (exact result under the same rotation, from the exact twin of this bundle's maps)
    r_img_e = rl.relight_numpy(env, rots[7], exact=True)
    rel_rot = float(np.linalg.norm(r_img_c[mask] - r_img_e[mask]) / np.linalg.norm(r_img_e[mask]))
    lp = rl.texel_light(env, rots[3])
    lp_t = lp / rl.sample_scale  # relight_texels takes flash units (texel_light's are scaled)
    k = rl.rank
    # What a user would write instead: the same rank-k product with NumPy/BLAS on float32 data
    # (basis images (3, k, P), the brightest texels' rows (n, 3, P)), written into a frame.
    # (the bundle's basis dequantised to float32, as a NumPy user would hold it)
    v32 = np.ascontiguousarray(rl.basis_f32().transpose(1, 2, 0))  # (3, k, P)
    coef = np.random.default_rng(0).random((3, k)).astype(np.float32)
    direct, _ = split_direct(lp, rl.transport.direct)
    rows32 = read_halves(rl.direct_rows(direct))  # (n, 3, P)
    dl = lp[direct].astype(np.float32)
    frame = np.zeros_like(rl.frame)
    flat = frame.reshape(-1, 3)

    def blas(i):
        for c in range(3):
            flat[rl.frame_index, c] = coef[c] @ v32[c] + dl[:, c] @ rows32[:, c]

    def blas_product(i):
        return [coef[c] @ v32[c] + dl[:, c] @ rows32[:, c] for c in range(3)]

    # "plain": the public API as the README shows it - relight(env, rotation=R) with the map
    # load_environment gave (read-only: known by identity) and a new result array every call.
    ms = _blocked_ms({"call": lambda i: rl.relight(env, rots[i], out=out), "plain": lambda i: rl.relight(env, rots[i]),
                      "kernel": lambda i: rl.relight_texels(lp_t),
                      "blas": blas, "blas_product": blas_product,
                      "direction": lambda i: rl.texel_light(env, rots[i])},
                     rounds=3 if quick else ROUNDS)
    # bytes read and written: the basis (8 and 4 bits), the step sizes, the exact texels' half
    # rows, frame index + RGB out
    c_bytes = ((-(-p // LANES)) * LANES * 3 * (rl.rank8 + rl.rank4 / 2 + 2 + (2 if rl.rank4 else 0))
               + rl.transport.direct * 3 * p * 2 + p * 16)
    c_np = _median_ms(lambda i: rl.relight_numpy(env, rots[i]), n=3, warmup=1)
    ent = {"path": f"compact tol {tol:g}", "tolerance": tol, "rank": k, "rel_l2_vs_exact": rel,
           "rel_l2_vs_exact_rotated": rel_rot, "ms_call": ms["call"], "ms_plain_call": ms["plain"],
           "ms_kernel": ms["kernel"],
           "ms_direction_stage": ms["direction"], "ms_call_per_100k": ms["call"] * per100k,
           "ms_kernel_per_100k": ms["kernel"] * per100k, "ms_numpy_twin": c_np,
           "ms_numpy_blas_same_product": ms["blas"], "ms_numpy_blas_product_only": ms["blas_product"],
           "bytes": c_bytes, "gbps": c_bytes / ms["kernel"] / 1e6, "basis_padded": int(rl._q8.shape[1])}
    if truth is not None:
        ent["psnr_vs_truth"], ent["gain"] = _psnr(c_img, truth, mask)
    return ent


def table(doc: dict) -> str:
    bw = doc["bandwidth"]
    lines = [f"{doc['pixels']} face pixels of a {doc['frame'][0]}x{doc['frame'][1]} frame, {doc['texels']} map texels; "
             f"{doc['device']}",
             f"memory read bandwidth: {bw['opencl_read_gbps']:.1f} GB/s (OpenCL float reads; measured again beside "
             f"each exact run), NumPy copy {bw['numpy_copy_gbps']:.1f} GB/s (read+write)",
             f"start (load bundle + build Relighter, fresh process): {doc['start']['warm_s']:.2f} s warm, "
             f"{doc['start']['first_s']:.2f} s first",
             "ms: medians, head turning every call; ms/call = the hot path (relight(env, R, out=out)), "
             "plain = relight(env, R) returning a new array; kernel = the per-pixel stage (device + one sync); "
             "BLAS = the same product with NumPy float32 + frame write",
             ""]
    head = (f"{'environment':14s} {'path':17s} {'rank':>4s} {'L2 vs exact':>11s} {'PSNR':>6s} {'ms/call':>8s} "
            f"{'plain':>6s} {'call/100k':>9s} {'kernel/100k':>11s} {'kernel':>7s} {'BLAS':>6s} {'NumPy twin':>10s} "
            f"{'GB/s':>5s} {'of BW':>5s}")
    lines += [head, "-" * len(head)]
    for row in doc["envs"]:
        for e in row["paths"]:
            ps = f"{e['psnr_vs_truth']:6.2f}" if "psnr_vs_truth" in e else "     -"
            blas = f"{e['ms_numpy_blas_same_product']:6.2f}" if "ms_numpy_blas_same_product" in e else "     -"
            frac = f"{e['bw_fraction']:5.2f}" if "bw_fraction" in e else "    -"
            plain = f"{e['ms_plain_call']:6.2f}" if "ms_plain_call" in e else "     -"
            lines.append(f"{row['env']:14s} {e['path']:17s} {str(e['rank'] or '-'):>4s} {e['rel_l2_vs_exact']:11.4f} "
                         f"{ps} {e['ms_call']:8.2f} {plain} {e['ms_call_per_100k']:9.2f} "
                         f"{e['ms_kernel_per_100k']:11.2f} {e['ms_kernel']:7.2f} {blas} {e['ms_numpy_twin']:10.1f} "
                         f"{e['gbps']:5.1f} {frac}")
    pl = doc["point_light"]
    lines.append(f"single point light (4 map texels): {pl['ms_call']:.2f} ms/call ({pl['ms_call_per_100k']:.2f} per "
                 f"100k px); through the full exact path: {pl['ms_via_full_exact_path']:.2f} ms")
    return "\n".join(lines)


def _plot(doc, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for row in doc["envs"]:
        xs = [e["ms_call_per_100k"] for e in row["paths"]]
        ys = [max(e["rel_l2_vs_exact"], 1e-5) for e in row["paths"]]
        line, = ax.plot(xs[1:], ys[1:], "o-", label=row["env"])
        ax.plot(xs[:1], ys[:1], "k*", ms=9)
        if row is doc["envs"][0]:
            for e, x, y in zip(row["paths"][1:], xs[1:], ys[1:], strict=True):
                ax.annotate(f"k={e['rank']}", (x, y), textcoords="offset points", xytext=(4, 5), fontsize=7,
                            color=line.get_color())
    ax.set_xscale("log")
    ax.set_yscale("log")
    lo, hi = ax.get_xlim()
    ax.set_xlim(min(lo, 0.8 * GOAL_MS_PER_100K), hi)
    ticks = [t for t in (0.5, 1, 2, 3, 5, 10, 20, 30, 50, 100) if min(ax.get_xlim()) <= t <= max(ax.get_xlim())]
    ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
    ax.minorticks_off()
    ax.axhline(GOAL_ERROR, color="0.6", lw=0.8, ls="--")
    ax.axvline(GOAL_MS_PER_100K, color="0.6", lw=0.8, ls=":")
    ax.text(GOAL_MS_PER_100K, GOAL_ERROR * 1.2,
            f" goal: <= {GOAL_ERROR:.0%} at <= {GOAL_MS_PER_100K:g} ms / 100k px", fontsize=7, color="0.4")
    ax.set_xlabel("ms per relight per 100k face pixels (median, head turning every call)")
    ax.set_ylabel("relative L2 error vs the exact path (exact: star at 1e-5)")
    ax.set_title(f"relight: error against run time ({doc['pixels']} px, {os.cpu_count()}-core CPU, PoCL)")
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
