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

import hashlib
import json
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .transport import split_direct

TOLERANCES = (0.05, 0.02, 0.01, 0.005, 0.002)
REPEATS = 40
WARMUP = 5


def _interleaved_ms(fns: dict, n=REPEATS, warmup=WARMUP) -> dict:
    """Median ms of several functions timed in turn (A B C A B C ...): on a shared machine whose
    speed drifts, alternating keeps the comparison fair."""
    for i in range(warmup):
        for f in fns.values():
            f(i)
    ts = {k: [] for k in fns}
    for i in range(n):
        for k, f in fns.items():
            t = time.perf_counter()
            f(warmup + i)
            ts[k].append(time.perf_counter() - t)
    return {k: float(np.median(v) * 1000.0) for k, v in ts.items()}


def _median_ms(fn, n=REPEATS, warmup=WARMUP) -> float:
    for i in range(warmup):
        fn(i)
    ts = []
    for i in range(n):
        t = time.perf_counter()
        fn(warmup + i)
        ts.append(time.perf_counter() - t)
    return float(np.median(ts) * 1000.0)


def measure_bandwidth(mb: int = 512) -> dict:
    """Memory bandwidth of this machine (GB/s): NumPy copy (read + write) and an OpenCL read kernel."""
    import pyopencl as cl

    from .runtime import get_runtime

    n = mb * (1 << 20) // 4
    a = np.ones(n, dtype=np.float32)
    b = np.empty_like(a)
    copy_ms = _median_ms(lambda i: np.copyto(b, a), n=5, warmup=2)
    rt = get_runtime()
    # Each work item streams its own contiguous chunk with 16-wide loads (the exact path's pattern).
    src = """__kernel void rd(__global const half *x, int per, __global float *out) {
        int g = get_global_id(0);
        __global const half *mine = x + (size_t)g * per * 16;
        float16 acc = (float16)(0.0f);
        for (int i = 0; i < per; ++i) acc += vload_half16(i, mine);
        out[g] = acc.s0 + acc.s5 + acc.sa + acc.sf; }"""
    prg = cl.Program(rt.context, src).build()
    k = cl.Kernel(prg, "rd")
    h = np.ones(n * 2, dtype=np.float16)  # the same bytes as `a`
    mf = cl.mem_flags
    hb = cl.Buffer(rt.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=h)
    groups = 4096
    ob = cl.Buffer(rt.context, mf.WRITE_ONLY, groups * 4)

    def run(i):
        k(rt.queue, (groups,), (64,), hb, np.int32(h.size // 16 // groups), ob)
        rt.queue.finish()

    read_ms = _median_ms(run, n=9, warmup=2)
    return {"numpy_copy_gbps": 2 * a.nbytes / copy_ms / 1e6, "opencl_read_gbps": h.nbytes / read_ms / 1e6}


def _frontal(env: np.ndarray) -> np.ndarray:
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
    from relight.pipeline.synth.studio import SynthConfig, synthesize

    out.mkdir(parents=True, exist_ok=True)
    front_studio = out / "front_studio.exr"
    front_sky = out / "front_sky.exr"
    if not front_studio.exists():
        write_image(front_studio, _frontal(load_environment("builtin:studio")))
        write_image(front_sky, _frontal(load_environment("builtin:sunset")))
    envs = {"sky (sunset)": "builtin:sunset", "studio": "builtin:studio", "small sun": "builtin:point:0.5,0.3,0.8",
            "front studio": str(front_studio), "front sky": str(front_sky)}
    size = (480, 270) if quick else (960, 540)
    cfg = SynthConfig(width=size[0], height=size[1], duration=10.0 if quick else 60.0, seed=0,
                      truth_envs=tuple(envs.values()))
    key = hashlib.sha1(json.dumps(asdict(cfg), sort_keys=True).encode()).hexdigest()[:10]
    cap = out / f"synth-{key}"
    if not (cap / "truth" / "meta.json").exists():
        if progress:
            print(f"synthesising a {size[0]}x{size[1]} capture ...", flush=True)
        synthesize(cap, cfg, progress=progress)
    bundle = out / f"{key}.bundle"
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

    from . import transport
    from .relighter import Relighter

    bundle_path, truth_dir, envs = _scenario(Path(out), quick, progress)
    bundle = relight.load_bundle(bundle_path)
    meta = json.loads((truth_dir / "meta.json").read_text())
    p = int(bundle.pixels.size)
    per100k = 1e5 / p
    mask = bundle.mask & (read_image(truth_dir / "mask.png")[..., 0] > 0.5)
    bw = measure_bandwidth(128 if quick else 512)
    read_bw = bw["opencl_read_gbps"]
    start = _start_time(bundle_path)
    rots = [rotation_matrix(8 * np.sin(i / 7), 4 * np.sin(i / 5), 2 * np.sin(i / 11)) for i in range(200)]
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
                               p, read_bw))
    # A single point light: the maps' own texels, no environment.
    light = np.array([0.5, 0.3, 0.8])
    pl_ms = _median_ms(lambda i: exact.relight_light(light + 0.01 * np.sin(i) * np.array([1, 0, 0])))
    pl_bytes = 4 * 3 * p * 2 + p * 12
    lp = transport.point_light(light, bundle.map_size, np.asarray(bundle.map_texels))
    pl_exact_ms = _median_ms(lambda i: exact._run_exact(lp))
    doc = {"pixels": p, "frame": list(bundle.frame_size), "map_size": list(bundle.map_size),
           "texels": int(bundle.map_texels.size), "bandwidth": bw, "start": start, "envs": rows,
           "point_light": {"ms_call": pl_ms, "ms_call_per_100k": pl_ms * per100k, "bytes": pl_bytes,
                           "ms_via_full_exact_path": pl_exact_ms},
           "device": exact.rt.description}
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


def _bench_env(name, env, exact, compacts, rots, mask, truth, p, read_bw) -> dict:
    """Every path on one environment."""
    per100k = 1e5 / p
    e_img = np.array(exact.relight(env))
    row = {"env": name, "paths": []}
    lp = exact.texel_light(env, rots[3])
    t = _interleaved_ms({"call": lambda i: exact.relight(env, rots[i]), "kernel": lambda i: exact._run_exact(lp)},
                        n=REPEATS // 2)
    e_ms, e_kernel = t["call"], t["kernel"]
    padded = np.zeros((exact.t_pad, 3))
    padded[:lp.shape[0]] = lp
    lit_blocks = int((np.abs(padded).reshape(-1, 16, 3).sum(axis=(1, 2)) > 0).sum())
    e_bytes = p * 3 * lit_blocks * 16 * 2 + p * 12
    e_np = _median_ms(lambda i: exact.relight_numpy(env, rots[i], exact=True), n=3, warmup=1)
    ent = {"path": "exact", "rank": None, "rel_l2_vs_exact": 0.0, "ms_call": e_ms, "ms_kernel": e_kernel,
           "ms_call_per_100k": e_ms * per100k, "ms_kernel_per_100k": e_kernel * per100k, "ms_numpy_twin": e_np,
           "bytes": e_bytes, "gbps": e_bytes / e_kernel / 1e6, "bw_fraction": e_bytes / e_kernel / 1e6 / read_bw}
    if truth is not None:
        ent["psnr_vs_truth"], ent["gain"] = _psnr(e_img, truth, mask)
    row["paths"].append(ent)
    for tol, rl in compacts.items():
        if not rl.exact:
            row["paths"].append(_bench_compact(tol, rl, env, exact, e_img, rots, mask, truth, p, read_bw))
    return row


def _bench_compact(tol, rl, env, exact, e_img, rots, mask, truth, p, read_bw) -> dict:
    per100k = 1e5 / p
    c_img = np.array(rl.relight(env))
    rel = float(np.linalg.norm(c_img[mask] - e_img[mask]) / np.linalg.norm(e_img[mask]))
    r_img_c = np.array(rl.relight(env, rots[7]))
    r_img_e = np.array(exact.relight(env, rots[7]))
    rel_rot = float(np.linalg.norm(r_img_c[mask] - r_img_e[mask]) / np.linalg.norm(r_img_e[mask]))
    lp = rl.texel_light(env, rots[3])
    k = rl.rank
    # What a user would write instead: the same rank-k product, float32, with BLAS, plus the
    # brightest texels from the texel-major maps.
    v32 = np.ascontiguousarray(np.asarray(rl._v[:, :, :k], dtype=np.float32).transpose(1, 2, 0, 3).reshape(3, k, -1))
    coef = np.random.default_rng(0).random((3, k)).astype(np.float32)
    direct, _ = split_direct(lp, rl.transport.direct)
    rows32 = np.asarray(rl.rows[direct], dtype=np.float32)  # (n, 3, P)
    dl = lp[direct].astype(np.float32)

    def blas(i):
        out = [coef[c] @ v32[c][:, :p] for c in range(3)]
        return [out[c] + dl[:, c] @ rows32[:, c] for c in range(3)]

    ms = _interleaved_ms({"call": lambda i: rl.relight(env, rots[i]), "kernel": lambda i: rl._run_compact(lp),
                          "blas": blas, "direction": lambda i: rl.texel_light(env, rots[i])}, n=2 * REPEATS)
    ms, ms_k, blas, ms_dir = ms["call"], ms["kernel"], ms["blas"], ms["direction"]
    c_bytes = rl._v.shape[0] * 16 * 3 * k * 2 + rl.transport.direct * 3 * p * 2 + p * 12
    c_np = _median_ms(lambda i: rl.relight_numpy(env, rots[i]), n=3, warmup=1)
    ent = {"path": f"compact tol {tol:g}", "tolerance": tol, "rank": k, "rel_l2_vs_exact": rel,
           "rel_l2_vs_exact_rotated": rel_rot, "ms_call": ms, "ms_kernel": ms_k, "ms_direction_stage": ms_dir,
           "ms_call_per_100k": ms * per100k, "ms_kernel_per_100k": ms_k * per100k, "ms_numpy_twin": c_np,
           "ms_numpy_blas_same_product": blas, "bytes": c_bytes, "gbps": c_bytes / ms_k / 1e6,
           "bw_fraction": c_bytes / ms_k / 1e6 / read_bw, "basis_padded": int(rl._v.shape[2])}
    if truth is not None:
        ent["psnr_vs_truth"], ent["gain"] = _psnr(c_img, truth, mask)
    return ent


def table(doc: dict) -> str:
    lines = [f"{doc['pixels']} face pixels of a {doc['frame'][0]}x{doc['frame'][1]} frame, {doc['texels']} map texels; "
             f"{doc['device']}",
             f"memory bandwidth: {doc['bandwidth']['opencl_read_gbps']:.1f} GB/s read (OpenCL), "
             f"{doc['bandwidth']['numpy_copy_gbps']:.1f} GB/s NumPy copy (read+write)",
             f"start (load bundle + build Relighter, fresh process): {doc['start']['warm_s']:.2f} s warm, "
             f"{doc['start']['first_s']:.2f} s first",
             ""]
    head = (f"{'environment':14s} {'path':18s} {'rank':>4s} {'L2 vs exact':>11s} {'PSNR':>6s} {'ms/call':>8s} "
            f"{'ms/100kpx':>9s} {'kernel/100k':>11s} {'NumPy twin':>10s} {'BLAS f32':>8s} {'GB/s':>6s} {'of BW':>6s}")
    lines += [head, "-" * len(head)]
    for row in doc["envs"]:
        for e in row["paths"]:
            ps = f"{e['psnr_vs_truth']:6.2f}" if "psnr_vs_truth" in e else "     -"
            blas = f"{e['ms_numpy_blas_same_product']:8.2f}" if "ms_numpy_blas_same_product" in e else "       -"
            lines.append(f"{row['env']:14s} {e['path']:18s} {str(e['rank'] or '-'):>4s} {e['rel_l2_vs_exact']:11.4f} "
                         f"{ps} {e['ms_call']:8.2f} {e['ms_call_per_100k']:9.2f} {e['ms_kernel_per_100k']:11.2f} "
                         f"{e['ms_numpy_twin']:10.1f} {blas} {e['gbps']:6.1f} {e['bw_fraction']:6.2f}")
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
        ax.plot(xs[1:], ys[1:], "o-", label=row["env"])
        ax.plot(xs[:1], ys[:1], "k*", ms=9)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axhline(0.01, color="0.6", lw=0.8, ls="--")
    ax.axvline(3.0, color="0.6", lw=0.8, ls=":")
    ax.set_xlabel("ms per relight per 100k face pixels (median, head turning every call)")
    ax.set_ylabel("relative L2 error vs the exact path (exact: star at 1e-5)")
    ax.set_title(f"relight: error against run time ({doc['pixels']} px, 2-core CPU, PoCL)")
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
