"""The house's rules that import-linter cannot state: no import cycles (function-local imports
included) and no private names imported across modules."""

from __future__ import annotations

import tomllib

import pytest

from .architecture import ROOT, drawn_edges, folder_edges, module_graph

#: Private names a module may take from another: the version string only.
ALLOWED_PRIVATE = {"__version__"}


@pytest.fixture(scope="module")
def graph():
    edges, taken = module_graph()
    private = [f"{m} takes {target}.{n}" for m, target, names in taken for n in names
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


def test_the_picture_of_the_folders_shows_the_code():
    """docs/architecture.png (docs/developing.md) is drawn from the imports; it carries the edges it
    shows, and they are the code's (which folder imports which; the widths may lag)."""
    drawn = drawn_edges()
    assert drawn is not None and set(drawn) == set(folder_edges()), \
        "the folders' imports moved on: redraw with `python -m tests.architecture`"
