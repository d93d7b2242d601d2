"""The package's boundaries, checked on its source: which layer may import which, and where SQL lives.

Layers, lowest first (docs/architecture.md): a module imports only from its own layer or one below it,
so data flows one way - task -> simulate -> objective -> optimizer -> store -> query -> CLI.
"""

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "cmrt"

LAYERS: list[tuple[str, set[str]]] = [
    ("foundation", {"errors", "inputs", "balance", "character", "curve", "ensemble", "control", "control.controller",
                    "control.kernel", "control.momentum", "control.planar", "control.references",
                    "control.stepping"}),
    ("physics", {"props", "reference", "task", "sequence", "library", "tick", "simulate", "objective", "validate",
                 "render"}),
    ("optimizer", {"checkpoint", "optimize", "memory", "parallel", "bench"}),
    ("store", {"store"}),
    ("service", {"warmstart", "jobs", "query", "interpolate", "plot"}),
    ("shell", {"cli", "launch"}),
]
RANK = {module: rank for rank, (_, modules) in enumerate(LAYERS) for module in modules}


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        name = ".".join(path.relative_to(PACKAGE).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = path
    return out


def _imports(path: Path) -> list[tuple[str, bool]]:
    """(imported cmrt module, imported inside a function) for every import in the file."""
    tree = ast.parse(path.read_text())
    inner = {id(n) for f in ast.walk(tree) if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)
             for n in ast.walk(f) if n is not f}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "cmrt":
            if node.module == "cmrt":
                found += [(a.name, id(node) in inner) for a in node.names]
            else:
                found.append((node.module.removeprefix("cmrt."), id(node) in inner))
    return found


def test_every_module_has_a_layer():
    assert set(_modules()) - {"__init__"} == set(RANK)


@pytest.mark.parametrize("module", sorted(RANK))
def test_imports_point_down(module):
    path = _modules()[module]
    for target, _ in _imports(path):
        assert RANK[target] <= RANK[module], f"{module} ({LAYERS[RANK[module]][0]}) imports {target} " \
                                             f"({LAYERS[RANK[target]][0]})"


def test_the_store_depends_on_nothing_but_errors():
    assert {t for t, _ in _imports(_modules()["store"])} <= {"errors"}


def test_only_the_shell_imports_the_job_queue():
    for module, path in _modules().items():
        if module not in ("cli", "__init__", "jobs"):
            assert "jobs" not in {t for t, _ in _imports(path)}, module


def test_no_sql_outside_the_store():
    sql = re.compile(r"\b(SELECT|INSERT INTO|UPDATE \w+ SET|DELETE FROM|CREATE TABLE|PRAGMA)\b")
    offenders = [f"{m}: {line.strip()}" for m, p in _modules().items() if m != "store"
                 for line in p.read_text().splitlines() if sql.search(line)]
    assert offenders == []


def test_imports_inside_functions_are_only_the_shells_lazy_heavy_ones():
    """An import inside a function must have a reason: each CLI verb imports what it uses when it runs
    (MuJoCo, numba, scipy, pycma, dask, matplotlib: ~4 s), so that the parser and the verbs that only read
    the store start at once, and ``query`` reads a run's task and curve (MuJoCo, scipy) only when asked for
    them. Anywhere else it would hide a cycle or a wrong-way edge. ``launch`` imports the CLI inside
    ``main`` so that a Ctrl-C during start-up is handled. (tests/test_cli.py checks what the verbs load.)"""
    lazy = {(m, t) for m, p in _modules().items() for t, inside in _imports(p) if inside}
    assert {(m, t) for m, t in lazy if m != "cli"} <= {("query", "curve"), ("query", "task"), ("launch", "cli")}
