"""The package's import graph, read from the code (every import, function-local ones included):
what tests/test_architecture.py checks, and the picture of the folders in docs/developing.md.

``python -m tests.architecture`` redraws docs/architecture.png from the code; the picture carries
the edges it shows (PNG text ``relight-edges``), so a test fails when the code has moved on.
"""

from __future__ import annotations

import ast
import json
import tomllib
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PICTURE = ROOT / "docs" / "architecture.png"
#: Top-level folders and the subpackage of `relight` each becomes (pyproject's package-dir; nested
#: packages are found under their top folder).
PACKAGES = {folder: pkg for pkg, folder in tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
            ["package-dir"].items() if "/" not in folder}
#: The picture's rows, top to bottom (the layers import-linter holds; a row's folders are
#: independent of each other), and what each box says under its folder's name.
ROWS = (("cli",), ("bench",), ("apps",), ("service",), ("engine", "pipeline", "pipeline/synth"), ("kernels",),
        ("relight",))
#: A lone folder's step aside from the middle (picture units; the picture is 3 wide).
STAGGER = {"bench": -0.8, "apps": 0.8}
CAPTIONS = {
    "cli": "the command line: relight, relight-serve",
    "bench": "benchmarks and evaluations",
    "apps": "relight filter, relight live",
    "service": "HTTP, websocket, WebRTC",
    "engine": "the per-frame engine",
    "pipeline": "the capture: video -> bundle",
    "pipeline/synth": "the synthetic studio",
    "kernels": "OpenCL kernels, the bundle, the relighter",
    "relight": "the core: colour, directions, video, images (every folder imports it)",
}


def modules() -> dict[str, Path]:
    """Every module of the package by dotted name, and its file."""
    out = {}
    for folder, pkg in PACKAGES.items():
        for f in sorted((ROOT / folder).rglob("*.py")):
            rel = f.relative_to(ROOT / folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            out[".".join([pkg, *parts])] = f
    return out


def imports(name: str, path: Path, known: set[str]):
    """(module imported, names taken) for every import in the file, nested ones included."""
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, ()
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                stem = base[:len(base) - node.level + 1]
                mod = ".".join(stem + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            names = [a.name for a in node.names]
            subs = [n for n in names if f"{mod}.{n}" in known]
            for s in subs:
                yield f"{mod}.{s}", ()
            yield mod, tuple(n for n in names if n not in subs)


def module_graph() -> tuple[dict[str, set[str]], list[tuple[str, str, tuple]]]:
    """(module -> the package's modules it imports; every (importer, module, names) import)."""
    mods = modules()
    known = set(mods)
    edges: dict[str, set[str]] = {m: set() for m in mods}
    taken = []
    for m, path in mods.items():
        for target, names in imports(m, path, known):
            while target and target not in known and "." in target:
                target = target.rsplit(".", 1)[0]  # `relight.kernels.bundle.Bundle` -> the module
            if target in known and target != m:
                edges[m].add(target)
                taken.append((m, target, names))
    return edges, taken


def folder_of(module: str) -> str:
    """The folder a module lives in, as the picture shows it (``pipeline/synth`` apart)."""
    parts = module.split(".")
    if parts[:3] == ["relight", "pipeline", "synth"]:
        return "pipeline/synth"
    if len(parts) > 1 and parts[1] in ("cli", "bench", "apps", "service", "engine", "pipeline", "kernels"):
        return parts[1]
    return "relight"


#: The package's front door, left out of the picture: ``relight/__init__.py`` (the public API,
#: importing the Relighter and the bundle's loader on first use) and ``python -m relight``.
FACADE = ("relight", "relight.__main__")


def folder_edges() -> dict[str, int]:
    """``"from -> to"``: how many modules of folder ``from`` import modules of ``to`` (the
    :data:`FACADE` left out)."""
    edges, _ = module_graph()
    count: Counter = Counter()
    for m, targets in edges.items():
        if m in FACADE:
            continue
        for t in {folder_of(t) for t in targets} - {folder_of(m)}:
            count[f"{folder_of(m)} -> {t}"] += 1
    return dict(sorted(count.items()))


def draw(path: Path = PICTURE) -> dict[str, int]:
    """Draw the folders and their imports (arrow width: importing modules) to ``path`` (PNG, the
    edges in its ``relight-edges`` text); the edges drawn."""
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    edges = folder_edges()
    where = {}
    for r, row in enumerate(ROWS):
        for c, folder in enumerate(row):
            # a lone folder steps aside from the one above it: long arrows pass between the boxes
            x = (c + 0.5) / len(row) * 3.0 if len(row) > 1 else 1.5 + STAGGER.get(folder, 0.0)
            where[folder] = (x, (len(ROWS) - 1 - r) * 1.0)
    fig, ax = plt.subplots(figsize=(11, 9))
    drawn = {k: n for k, n in edges.items() if not k.endswith("-> relight")}  # every folder uses the core
    outs: dict[str, list] = {}
    ins: dict[str, list] = {}
    for key in drawn:
        a, b = key.split(" -> ")
        outs.setdefault(a, []).append(b)
        ins.setdefault(b, []).append(a)

    def slot(folder, others, other):
        """An arrow's end on ``folder``'s box: spread along it in the order of the other ends' places."""
        order = sorted(others, key=lambda f: (where[f][0], -where[f][1]))
        k = order.index(other)
        return where[folder][0] + 0.66 * ((k + 0.5) / len(order) - 0.5)

    def bend(start, end, a, b):
        """0 for a straight arrow that meets no other box, else a curve out to the side."""
        t = np.linspace(0.05, 0.95, 40)[:, None]
        pts = np.asarray(start) * (1 - t) + np.asarray(end) * t
        hit = any(((np.abs(pts[:, 0] - x) < 0.44) & (np.abs(pts[:, 1] - y) < 0.2)).any()
                  for f, (x, y) in where.items() if f not in (a, b))
        return (0.3 if start[0] >= 1.5 else -0.3) if hit else 0.0

    for key, n in drawn.items():
        a, b = key.split(" -> ")
        (_, y0), (_, y1) = where[a], where[b]
        start, end = (slot(a, outs[a], b), y0 - 0.17), (slot(b, ins[b], a), y1 + 0.17)
        if abs(y0 - y1) < 0.5:  # the same row: side by side
            start, end = (where[a][0] + 0.42, y0), (where[b][0] - 0.42, y1)
        ax.add_patch(FancyArrowPatch(start, end, arrowstyle="-|>", mutation_scale=11, lw=0.5 + 0.3 * n ** 0.5,
                                     color="#446", alpha=0.6, shrinkA=0, shrinkB=0,
                                     connectionstyle=f"arc3,rad={bend(start, end, a, b)}"))
    for folder, (x, y) in where.items():
        ax.add_patch(FancyBboxPatch((x - 0.42, y - 0.17), 0.84, 0.34, boxstyle="round,pad=0.02", fc="#eef2fb",
                                    ec="#334", lw=1.2))
        ax.text(x, y + 0.05, f"{folder}/", ha="center", va="center", fontsize=11, weight="bold")
        ax.text(x, y - 0.08, CAPTIONS[folder], ha="center", va="center", fontsize=7.5)
    ax.set_xlim(-0.1, 3.1)
    ax.set_ylim(-0.5, len(ROWS) - 0.5)
    ax.axis("off")
    ax.set_title("relight's folders and their imports, read from the code (arrow: imports; width: how many "
                 "modules; the core's arrows left out)\nread bottom-up as the data flows: video -> capture -> "
                 "bundle -> relight -> frame -> service and applications", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"relight-edges": json.dumps(edges, sort_keys=True)})
    plt.close(fig)
    return edges


def drawn_edges(path: Path = PICTURE) -> dict[str, int] | None:
    """The edges a picture drawn by :func:`draw` shows (None: no such picture)."""
    from PIL import Image

    if not path.exists():
        return None
    with Image.open(path) as im:
        text = im.info.get("relight-edges")
    return None if text is None else json.loads(text)


if __name__ == "__main__":
    drawn = draw()
    print(f"wrote {PICTURE.relative_to(ROOT)}: {len(drawn)} edges between {len(set(sum(ROWS, ())))} folders")
