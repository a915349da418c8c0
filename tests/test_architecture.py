"""The house's rules that import-linter cannot state: no import cycles (function-local imports
included) and no private names imported across modules."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: Top-level folders and the subpackage of `relight` each becomes (pyproject's package-dir; nested
#: packages are found under their top folder).
PACKAGES = {folder: pkg for pkg, folder in tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
            ["package-dir"].items() if "/" not in folder}
#: Private names a module may take from another: the version string only.
ALLOWED_PRIVATE = {"__version__"}


def _modules() -> dict[str, Path]:
    out = {}
    for folder, pkg in PACKAGES.items():
        for f in sorted((ROOT / folder).rglob("*.py")):
            rel = f.relative_to(ROOT / folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            out[".".join([pkg, *parts])] = f
    return out


def _imports(name: str, path: Path, known: set[str]):
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


@pytest.fixture(scope="module")
def graph():
    mods = _modules()
    known = set(mods)
    edges: dict[str, set[str]] = {m: set() for m in mods}
    private = []
    for m, path in mods.items():
        for target, names in _imports(m, path, known):
            while target and target not in known and "." in target:
                target = target.rsplit(".", 1)[0]  # `relight.kernels.bundle.Bundle` -> the module
            if target in known and target != m:
                edges[m].add(target)
                private += [f"{m} takes {target}.{n}" for n in names
                            if n.startswith("_") and n not in ALLOWED_PRIVATE]
    return edges, private


def test_the_scan_sees_the_package(graph):
    edges, _ = graph
    assert len(edges) > 60
    assert "relight.kernels.recipe" in edges["relight.kernels.bundle"]  # a function-local import


def test_no_import_cycles(graph):
    edges, _ = graph
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles = []

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                cycles.append(sorted(group))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    assert cycles == [], f"import cycles: {cycles}"


def test_no_private_names_across_modules(graph):
    _, private = graph
    assert private == [], "\n".join(private)


def test_every_core_module_is_held_to_the_core_contract():
    """Each module of the core (``relight/*.py``) is listed in import-linter's "the core imports no
    layer above it" contract: a new core module would otherwise import the layers above unchecked."""
    doc = tomllib.loads((ROOT / "pyproject.toml").read_text())
    contracts = doc["tool"]["importlinter"]["contracts"]
    core = next(c for c in contracts if c["name"] == "the core imports no layer above it")
    listed = set(core["source_modules"])
    files = {f"relight.{f.stem}" for f in (ROOT / "relight").glob("*.py") if not f.stem.startswith("_")}
    assert files - listed == set(), f"core modules outside the contract: {sorted(files - listed)}"
