"""The summary and the writing of ``relight bench accuracy``: per-variant means over the scenes,
the goal checks (``full`` over the baselines, the real faces, the default bundle against its
exact maps), the error-against-run-time plot, ``report.md`` and the console table."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .accuracy_real import FACE_HOLDOUT
from .variants import BASELINES, VARIANTS

#: Goals on the real faces: ``full`` over the best other method (baselines and the nearest photo),
#: mean over the subjects and on every subject (dB).
FACE_GOAL_MEAN_DB = 2.0
FACE_GOAL_EACH_DB = 1.0
#: The default bundle (recipe, compact transport) against its exact maps: goals of issue 14.
DEFAULT_BUNDLE_DB = 0.1
DEFAULT_BUNDLE_KB = 1.0


def _mean(xs) -> float | None:
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    return float(np.mean(xs)) if xs else None


def summarise(doc: dict) -> dict:
    """Per variant: mean PSNR / SSIM over scenes x environments (in hull, whole sphere), OLAT
    relative errors, Dome PSNR / SSIM, and run time; plus the goal check (full vs each baseline)."""
    names = list(VARIANTS)
    out = {}
    for v in names:
        rows = [s["variants"][v] for s in doc["scenes"] if v in s["variants"]]
        r = {}
        for kind in ("in hull", "whole sphere"):
            envs = [e for row in rows for e in row["envs"].values() if e["kind"] == kind]
            r[f"psnr {kind}"] = _mean(e["psnr"] for e in envs)
            r[f"ssim {kind}"] = _mean(e["ssim"] for e in envs)
        r["psnr all"] = _mean(e["psnr"] for row in rows for e in row["envs"].values())
        r["olat whole"] = _mean(row["olat"]["rel_rmse_whole"] for row in rows)
        r["olat hull"] = _mean(row["olat"]["rel_rmse_hull"] for row in rows)
        r["capture s"] = _mean(row["capture_s"] for row in rows)
        r["maps s"] = _mean(row["maps_s"] for row in rows)
        r["bundle MB"] = _mean(row["bundle_mb"] for row in rows)
        r["relight ms"] = _mean(row["relight_ms"] for row in rows)
        dome = (doc.get("dome") or {}).get("variants", {}).get(v)
        r["dome psnr"] = dome["psnr"] if dome else None
        r["dome ssim"] = dome["ssim"] if dome else None
        out[v] = r
    goal = {}
    for key in ("psnr all", "dome psnr"):
        full = out["full"][key]
        best = max(((out[b][key], b) for b in BASELINES if out[b][key] is not None), default=(None, None))
        goal[key] = {"full": full, "best_baseline": best[1], "best_baseline_value": best[0],
                     "margin_db": None if full is None or best[0] is None else full - best[0]}
    return {"variants": out, "goal": goal, "default_bundle": default_bundle(doc)}


def default_bundle(doc: dict) -> dict:
    """The ``full`` variant as ``relight capture`` writes it by default (its maps' recipe, the
    8/4-bit compact transport) against its exact maps: mean PSNR of both per source (synthetic
    scenes x environments, Dome, each real face), the difference (goal: within
    ``DEFAULT_BUNDLE_DB``) and its size per face pixel (goal: <= ``DEFAULT_BUNDLE_KB``)."""
    rows = []
    for sc in doc.get("scenes", []):
        v = sc["variants"].get("full")
        if v and v.get("default_psnr"):
            exact = _mean(v["envs"][k]["psnr"] for k in v["default_psnr"])
            rows.append({"source": f"synthetic {sc['name']}", "exact": exact,
                         "default": _mean(v["default_psnr"].values()), "kb_per_px": v.get("default_kb_per_px")})
    dome = (doc.get("dome") or {}).get("variants", {}).get("full")
    if dome and dome.get("default_psnr") is not None:
        rows.append({"source": "rti-dome", "exact": dome["psnr"], "default": dome["default_psnr"],
                     "kb_per_px": dome.get("default_kb_per_px")})
    for f in doc.get("faces") or []:
        v = f["variants"].get("full")
        if v and v.get("default_psnr") is not None:
            rows.append({"source": f"face {f['subject']}", "exact": v["psnr"], "default": v["default_psnr"],
                         "kb_per_px": v.get("default_kb_per_px")})
    for r in rows:
        r["difference_db"] = None if r["exact"] is None or r["default"] is None else r["default"] - r["exact"]
    diffs = [abs(r["difference_db"]) for r in rows if r["difference_db"] is not None]
    kbs = [r["kb_per_px"] for r in rows if r["kb_per_px"] is not None]
    return {"rows": rows, "worst_difference_db": max(diffs) if diffs else None,
            "largest_kb_per_px": max(kbs) if kbs else None,
            "goal_met": bool(diffs) and max(diffs) <= DEFAULT_BUNDLE_DB and bool(kbs) and max(kbs) <= DEFAULT_BUNDLE_KB}


def summarise_faces(faces: list[dict]) -> dict | None:
    """Per variant the mean PSNR / SSIM over the subjects; the goal check (full against the best
    other method, mean and per subject)."""
    if not faces:
        return None
    names = list(faces[0]["variants"])
    mean = {n: {"psnr": _mean(f["variants"][n]["psnr"] for f in faces),
                "ssim": _mean(f["variants"][n]["ssim"] for f in faces)} for n in names}
    margins = {f["subject"]: f["margin_db"] for f in faces}
    m = _mean(margins.values())
    return {"variants": mean, "margins_db": margins, "mean_margin_db": m,
            "goal_met": m is not None and m >= FACE_GOAL_MEAN_DB and
            all(v is not None and v >= FACE_GOAL_EACH_DB for v in margins.values())}


def pareto_plot(doc: dict, path: Path) -> None:
    """Mean PSNR against capture time and relight time, one point per variant, the Pareto
    front (no variant both faster and more accurate) joined."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = doc["summary"]["variants"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    panels = [("capture s", "psnr all", "capture time (s, mean over scenes)", "mean PSNR, synth (dB)"),
              ("relight ms", "psnr all", "relight call (ms, default compact path)", "mean PSNR, synth (dB)"),
              ("capture s", "dome psnr", "capture time (s, Dome set)", "PSNR on held-out photos (dB)")]
    for ax, (xk, yk, xl, yl) in zip(axes, panels, strict=True):
        pts = [(v[xk], v[yk], n) for n, v in s.items() if v[xk] is not None and v[yk] is not None]
        if yk == "dome psnr" and doc.get("dome"):
            pts = [(doc["dome"]["variants"][n]["capture_s"], y, n) for _, y, n in pts]
        for x, y, n in pts:
            ax.scatter(x, y, color="C3" if n.startswith("full") else "C0", zorder=3)
            ax.annotate(n, (x, y), textcoords="offset points", xytext=(4, 3), fontsize=8)
        front = sorted([p for p in pts if not any(q[0] <= p[0] and q[1] > p[1] or q[0] < p[0] and q[1] >= p[1]
                                                   for q in pts)])
        if front:
            ax.plot([p[0] for p in front], [p[1] for p in front], "--", color="grey", lw=1)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
    fig.suptitle("error against run time (up and left is better; dashed: Pareto front)")
    fig.tight_layout()
    from relight.imageio import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _f(v, fmt="{:.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def report_markdown(doc: dict) -> str:
    """``report.md``: the goals, the headline table, the default bundle, the per-scene and
    per-environment tables, the real photos and faces, the heat maps and the stability suite."""
    s = doc["summary"]
    names = list(VARIANTS)
    lines = ["# Accuracy report (`relight bench accuracy`" + (" --quick" if doc["quick"] else "") + ")", ""]
    lines += _goal_lines(doc, s["goal"])
    lines += _headline_lines(s, names)
    lines += _default_bundle_lines(s.get("default_bundle") or {})
    lines += _scene_lines(doc, names)
    lines += _environment_lines(doc, names)
    if doc.get("dome"):
        lines += _dome_lines(doc["dome"], names)
    if doc.get("faces"):
        lines += _face_lines(doc)
    lines += _heat_map_lines(doc)
    lines += _stability_lines(doc)
    lines += ["", f"Run time of this report: {doc['seconds']:.0f} s.", ""]
    return "\n".join(lines)


def _goal_lines(doc: dict, g: dict) -> list[str]:
    """Report lines: the goal `full` >= 1 dB over every baseline, synthetic and real photos."""
    lines = ["## Goal: `full` >= 1 dB over every baseline", ""]
    for key, label in (("psnr all", "synthetic scenes, mean PSNR over scenes x environments"),
                       ("dome psnr", "real held-out photos (rti-dome Test), mean PSNR")):
        r = g[key]
        if r["full"] is None:
            lines.append(f"* {label}: not measured ({doc.get('dome_skipped')})")
        else:
            ok = r["margin_db"] is not None and r["margin_db"] >= 1.0
            lines.append(f"* {label}: full {r['full']:.2f} dB, best baseline {r['best_baseline']} "
                         f"{r['best_baseline_value']:.2f} dB, margin {r['margin_db']:+.2f} dB - "
                         + ("met" if ok else "**not met**"))
    return lines


def _headline_lines(s: dict, names: list[str]) -> list[str]:
    """Report lines: the headline table, one row per variant of the summary ``s``."""
    lines = ["", "## Headline", "",
             "PSNR / SSIM after one exposure gain inside the face mask, mean over scenes; OLAT: RMS error of "
             "single-light renders relative to the truth's RMS (solid-angle weighted), whole sphere / captured "
             "hull; Dome: 20 real held-out photos, sRGB, no gain; time: capture (shared preparation + the "
             "variant's maps), relight call (default compact path).", "",
             "| variant | PSNR in hull | PSNR whole sphere | SSIM in hull | SSIM whole | OLAT err whole | "
             "OLAT err hull | Dome PSNR | Dome SSIM | capture s | maps s | bundle MB | relight ms |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for n in names:
        v = s["variants"][n]
        lines.append(f"| {n} | {_f(v['psnr in hull'])} | {_f(v['psnr whole sphere'])} | "
                     f"{_f(v['ssim in hull'], '{:.4f}')} | {_f(v['ssim whole sphere'], '{:.4f}')} | "
                     f"{_f(v['olat whole'], '{:.3f}')} | {_f(v['olat hull'], '{:.3f}')} | {_f(v['dome psnr'])} | "
                     f"{_f(v['dome ssim'], '{:.4f}')} | {_f(v['capture s'], '{:.1f}')} | {_f(v['maps s'], '{:.2f}')} | "
                     f"{_f(v['bundle MB'], '{:.1f}')} | {_f(v['relight ms'])} |")
    return lines


def _default_bundle_lines(db: dict) -> list[str]:
    """Report lines: the default bundle against its exact maps (``db``: :func:`default_bundle`), or none."""
    if not db.get("rows"):
        return []
    lines = ["", f"## The default bundle: recipe + 8/4-bit compact transport against the exact maps (goal: "
             f"within {DEFAULT_BUNDLE_DB} dB, <= {DEFAULT_BUNDLE_KB:g} KB per face pixel)", "",
             "`full` relit from the bundle `relight capture` writes by default (the maps' recipe: texels "
             "made on demand, the compact transport at the default tolerance) and from its exact maps "
             "(`--keep-maps`, `--exact`); mean PSNR as in the tables below.", "",
             "| source | exact maps dB | default bundle dB | difference dB | KB per face pixel |",
             "|---|---|---|---|---|"]
    for r in db["rows"]:
        lines.append(f"| {r['source']} | {_f(r['exact'])} | {_f(r['default'])} | "
                     f"{_f(r['difference_db'], '{:+.3f}')} | {_f(r['kb_per_px'], '{:.3f}')} |")
    lines.append("")
    lines.append(f"Worst difference {_f(db['worst_difference_db'], '{:.3f}')} dB, largest bundle "
                 f"{_f(db['largest_kb_per_px'], '{:.3f}')} KB per face pixel: goal "
                 + ("met" if db["goal_met"] else "**not met**") + ".")
    return lines


def _scene_lines(doc: dict, names: list[str]) -> list[str]:
    """Report lines: the error-against-time plot, the method x scene PSNR table and the scenes."""
    lines = ["", "![error against run time](error_vs_time.png)", "",
             "## Method x scene (PSNR dB: in hull / whole sphere)", ""]
    lines.append("| variant | " + " | ".join(sc["name"] for sc in doc["scenes"]) + " |")
    lines.append("|---|" + "---|" * len(doc["scenes"]))
    for n in names:
        cells = []
        for sc in doc["scenes"]:
            e = sc["variants"][n]["envs"]
            ih = _mean(x["psnr"] for x in e.values() if x["kind"] == "in hull")
            ws = _mean(x["psnr"] for x in e.values() if x["kind"] == "whole sphere")
            cells.append(f"{_f(ih)} / {_f(ws)}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines += ["", "Scenes:", ""]
    for sc in doc["scenes"]:
        c = sc["config"]
        v = sc["variants"]["full"]
        lines.append(f"* {sc['name']}: {c['width']}x{c['height']}, {c['duration']:g} s, seed {c['seed']}, flash "
                     f"{c['flash_hz']:g} Hz, head motion x{c['head_motion']:g}, camera drift {c['camera_drift']}, "
                     f"sparse sides {c.get('sparse_sides', False)}; {v['samples']} light samples, {v['pixels']} face "
                     f"pixels, hull {100 * v['hull_share']:.0f} % of the sphere")
    return lines


def _environment_lines(doc: dict, names: list[str]) -> list[str]:
    """Report lines: the environments and the per-environment PSNR / SSIM table (mean over scenes)."""
    lines = ["", "Environments: " + ", ".join(f"{k} ({e['kind']})" for k, e in doc["envs"].items()), ""]
    lines += ["## Per-environment PSNR / SSIM (mean over scenes)", "",
              "| variant | " + " | ".join(doc["envs"]) + " |", "|---|" + "---|" * len(doc["envs"])]
    for n in names:
        cells = []
        for k in doc["envs"]:
            ps = _mean(sc["variants"][n]["envs"][k]["psnr"] for sc in doc["scenes"])
            ss = _mean(sc["variants"][n]["envs"][k]["ssim"] for sc in doc["scenes"])
            cells.append(f"{_f(ps)} / {_f(ss, '{:.3f}')}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return lines


def _dome_lines(d: dict, names: list[str]) -> list[str]:
    """Report lines: every variant on the rti-dome set's held-out photos (``d``: the doc's ``dome``)."""
    lines = ["", f"## Real held-out photos: rti-dome ({d['lights_in']} lights in, {d['held_out']} held out, "
             f"{d['image_size'][0]}x{d['image_size'][1]} px"
             + (" - shrunk for --quick)" if d["scale"] > 1 else ")"),
             "", "| variant | PSNR (dB) | SSIM | worst light PSNR | capture s | bundle MB |",
             "|---|---|---|---|---|---|"]
    for n in names:
        r = d["variants"][n]
        lines.append(f"| {n} | {r['psnr']:.2f} | {r['ssim']:.4f} | {min(r['psnr_per_light']):.2f} | "
                     f"{r['capture_s']:.1f} | {r['bundle_mb']:.1f} |")
    return lines


def _face_lines(doc: dict) -> list[str]:
    """Report lines: the real faces - PSNR per subject and variant, the goal, each held-out light."""
    fs = doc["faces_summary"]
    f0 = doc["faces"][0]
    names_f = list(f0["variants"])
    lines = ["", f"## Real faces: {len(doc['faces'])} subject(s), every {FACE_HOLDOUT}th light held out", "",
             f"Each subject's photos ({f0['image_size'][0]}x{f0['image_size'][1]}, decoded as "
             f"{f0['transfer']}) minus the held-out lights build the bundles; each held-out photo is "
             "predicted by `render --light` plus the set's room-light frame; PSNR / SSIM sRGB-encoded over "
             "the face, no gain. `nearest`: the captured photo whose light is closest.", "",
             "| variant | " + " | ".join(f["subject"] for f in doc["faces"]) + " | mean PSNR | mean SSIM |",
             "|---|" + "---|" * (len(doc["faces"]) + 2)]
    for n in names_f:
        cells = [f"{f['variants'][n]['psnr']:.2f}" for f in doc["faces"]]
        v = fs["variants"][n]
        lines.append(f"| {n} | " + " | ".join(cells) + f" | {_f(v['psnr'])} | {_f(v['ssim'], '{:.4f}')} |")
    lines += ["", "Goal: `full` >= the best other method (baselines, nearest photo) + "
              f"{FACE_GOAL_MEAN_DB:g} dB mean, + {FACE_GOAL_EACH_DB:g} dB on every subject: margins "
              + ", ".join(f"{f['subject']} {f['margin_db']:+.2f} dB (over {f['best_other']})" for f in doc["faces"])
              + f"; mean {fs['mean_margin_db']:+.2f} dB - " + ("met" if fs["goal_met"] else "**not met**"), "",
              "Per held-out light (PSNR dB, full / best other):", ""]
    for f in doc["faces"]:
        pf, po = f["variants"]["full"]["psnr_per_light"], f["variants"][f["best_other"]]["psnr_per_light"]
        lines.append(f"* {f['subject']}: " + ", ".join(f"{n.split('.')[0]} {a:.1f}/{b:.1f}"
                                                     for n, a, b in zip(f["held_out"], pf, po, strict=True)))
    return lines


def _heat_map_lines(doc: dict) -> list[str]:
    """Report lines: each scene's OLAT error heat map (the paper's Fig. 14)."""
    lines = ["", "## Error heat maps (the paper's Fig. 14)", "",
             "Per pixel: RMS error of single-light renders over all 32x16 light directions (top) and over the "
             "captured hull only (bottom), solid-angle weighted; one colour scale per row and scene.", ""]
    for sc in doc["scenes"]:
        lines.append(f"![{sc['name']}]({sc['heat_map']})")
    return lines


def _stability_lines(doc: dict) -> list[str]:
    """Report lines: the numerical stability suite, one row per case and variant."""
    lines = ["", "## Numerical stability", "",
             "Each case through every variant; max error relative to a float64 reference; finite = every output "
             "finite. A clear error for invalid input counts as handled.", "",
             "| case | variant | max rel. error | finite | note |", "|---|---|---|---|---|"]
    for r in doc["stability"]:
        note = (r.get("error") or "").replace("|", "/")[:90]
        lines.append(f"| {r['case']} | {r['variant']} | {_f(r.get('max_rel_error'), '{:.2e}')} | "
                     f"{'yes' if r['finite'] else '**no**'} | {note} |")
    return lines


def table(doc: dict) -> str:
    s = doc["summary"]
    lines = [f"{'variant':18s} {'PSNR hull':>9s} {'PSNR whole':>10s} {'OLAT whole':>10s} {'OLAT hull':>9s} "
             f"{'Dome PSNR':>9s} {'capture s':>9s} {'relight ms':>10s}"]
    for n, v in s["variants"].items():
        lines.append(f"{n:18s} {_f(v['psnr in hull']):>9s} {_f(v['psnr whole sphere']):>10s} "
                     f"{_f(v['olat whole'], '{:.3f}'):>10s} {_f(v['olat hull'], '{:.3f}'):>9s} "
                     f"{_f(v['dome psnr']):>9s} {_f(v['capture s'], '{:.1f}'):>9s} {_f(v['relight ms']):>10s}")
    for key, r in s["goal"].items():
        if r["margin_db"] is not None:
            lines.append(f"goal ({key}): full {r['full']:.2f} dB vs best baseline {r['best_baseline']} "
                         f"{r['best_baseline_value']:.2f} dB: margin {r['margin_db']:+.2f} dB (need >= +1)")
    fs = doc.get("faces_summary")
    if fs:
        for f in doc["faces"]:
            lines.append(f"real face {f['subject']}: full {f['variants']['full']['psnr']:.2f} dB, best other "
                         f"{f['best_other']} {f['variants'][f['best_other']]['psnr']:.2f} dB: "
                         f"margin {f['margin_db']:+.2f} dB (need >= +{FACE_GOAL_EACH_DB:g})")
        lines.append(f"real faces: mean margin {fs['mean_margin_db']:+.2f} dB (need >= +{FACE_GOAL_MEAN_DB:g}): "
                     + ("met" if fs["goal_met"] else "not met"))
    db = s.get("default_bundle") or {}
    for r in db.get("rows", []):
        lines.append(f"default bundle, {r['source']}: {_f(r['default'])} dB vs exact maps {_f(r['exact'])} dB "
                     f"({_f(r['difference_db'], '{:+.3f}')}), {_f(r['kb_per_px'], '{:.3f}')} KB per face pixel")
    if db.get("rows"):
        lines.append(f"default bundle: worst {_f(db['worst_difference_db'], '{:.3f}')} dB "
                     f"(need <= {DEFAULT_BUNDLE_DB}), largest {_f(db['largest_kb_per_px'], '{:.3f}')} KB/px "
                     f"(need <= {DEFAULT_BUNDLE_KB:g}): "
                     + ("met" if db["goal_met"] else "not met"))
    bad = [r for r in doc["stability"] if not r["finite"]]
    lines.append(f"stability: {len(doc['stability'])} case x variant runs, non-finite: {len(bad)}")
    return "\n".join(lines)
