"""The package's boundaries, checked on its source: which layer may import which, and where SQL lives.

One package per layer (docs/architecture.md), lowest first; a module imports only from its own layer or
one below it, so data flows one way - body -> control -> motion -> sim -> optimize -> service -> viz ->
dashboard -> cli.
The top-level modules (``errors``, ``modes``, ``inputs``) are the base every layer may use.
"""

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "cmrt"

#: Layers, lowest first: a package each, the base its top-level modules.
LAYERS: list[tuple[str, set[str]]] = [
    ("base", {"errors", "modes", "inputs"}),
    ("body", {"body"}),
    ("control", {"control"}),
    ("motion", {"motion"}),
    ("sim", {"sim"}),
    ("optimize", {"optimize"}),
    ("service", {"service"}),
    ("viz", {"viz"}),
    ("dashboard", {"dashboard"}),
    ("cli", {"cli"}),
]
RANK = {top: rank for rank, (_, tops) in enumerate(LAYERS) for top in tops}


def _modules() -> dict[str, Path]:
    """Every module by dotted name inside cmrt (``sim.simulate``; a package by its own name, ``sim``)."""
    out = {}
    for path in PACKAGE.rglob("*.py"):
        name = ".".join(path.relative_to(PACKAGE).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = path
    return out


MODULES = _modules()


def layer(module: str) -> str:
    """The layer of a module (``sim.tick`` -> ``sim``; ``errors`` -> ``errors``)."""
    return module.split(".")[0]


def _target(package: str, name: str) -> str:
    """What ``from cmrt.<package> import <name>`` imports: the submodule ``name`` if there is one, else
    (a name defined in the package's module) the package itself."""
    full = f"{package}.{name}" if package else name
    return full if full in MODULES else package or "__init__"


def _imports(path: Path) -> list[tuple[str, list[str], bool]]:
    """(imported cmrt module, names taken from it, whether the import is inside a function) for every import
    in the file (those under ``if TYPE_CHECKING`` too: a circle a type checker sees is a circle)."""
    tree = ast.parse(path.read_text())
    inner = {id(n) for f in ast.walk(tree) if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)
             for n in ast.walk(f) if n is not f}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "cmrt":
            package = node.module.removeprefix("cmrt").removeprefix(".")
            for alias in node.names:
                found.append((_target(package, alias.name), [alias.name], id(node) in inner))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "cmrt" and alias.name != "cmrt":
                    found.append((alias.name.removeprefix("cmrt."), [], id(node) in inner))
    return found


def _edges() -> dict[str, set[str]]:
    return {m: {t for t, _, _ in _imports(p)} - {m} for m, p in MODULES.items()}


def test_cmrt_holds_one_folder_per_layer_and_the_base_modules():
    """``ls cmrt/``: the layers' packages and the base modules, nothing else."""
    entries = {p.name for p in PACKAGE.iterdir() if p.name != "__pycache__"}
    assert entries == {"__init__.py", "errors.py", "modes.py", "inputs.py"} | {
        top for _, tops in LAYERS[1:] for top in tops}


def test_every_module_has_a_layer():
    assert {layer(m) for m in MODULES} - {"__init__"} == set(RANK)


def test_every_layer_has_a_readme():
    for _, tops in LAYERS[1:]:
        for top in tops:
            readme = PACKAGE / top / "README.md"
            assert readme.is_file(), readme
            assert 5 <= len(readme.read_text().splitlines()) <= 25, readme


@pytest.mark.parametrize("module", sorted(set(MODULES) - {"__init__"}))
def test_imports_point_down(module):
    for target, _, _ in _imports(MODULES[module]):
        assert target != "__init__", f"{module} imports the top-level API (cmrt/__init__.py)"
        assert RANK[layer(target)] <= RANK[layer(module)], \
            f"{module} ({layer(module)}) imports {target} ({layer(target)}): an upward import"


def test_no_import_circle():
    """No module reaches itself through imports (a lazy one inside a function counts too)."""
    edges = _edges()
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(edges.get(module, ())):
            if state.get(target) == 1:
                cycle = path[path.index(target):] + [target] if target in path else [module, target]
                pytest.fail(f"import circle: {' -> '.join(cycle)}")
            if target not in state:
                visit(target, path + [target])
        state[module] = 2

    for module in sorted(edges):
        if module not in state:
            visit(module, [module])


def _private_uses(module: str, path: Path) -> list[str]:
    """Underscore names of another layer's modules that ``module`` uses: imported by name, or read as an
    attribute of an imported module (``kernel._x``)."""
    out = []
    modules_bound = {}  # local name -> cmrt module it is bound to
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "cmrt":
            package = node.module.removeprefix("cmrt").removeprefix(".")
            for alias in node.names:
                target = _target(package, alias.name)
                if target == (f"{package}.{alias.name}" if package else alias.name):
                    modules_bound[alias.asname or alias.name] = target
                elif alias.name.startswith("_") and layer(target) != layer(module):
                    out.append(f"{target}.{alias.name}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname and alias.name.startswith("cmrt."):
                    modules_bound[alias.asname] = alias.name.removeprefix("cmrt.")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.attr.startswith("_") \
                and not node.attr.startswith("__"):
            target = modules_bound.get(node.value.id)
            if target is not None and layer(target) != layer(module):
                out.append(f"{target}.{node.attr}")
    return out


def test_no_layer_uses_another_layers_private_names():
    """A leading underscore is private to its layer: another layer uses only public names."""
    offenders = {m: uses for m, p in MODULES.items() if (uses := _private_uses(m, p))}
    assert offenders == {}


def test_modes_are_constants_and_the_controller_reads_no_user_input_checks():
    """``modes`` imports nothing; the controller's modes come from it, not from the CLI's ``inputs``."""
    tree = ast.parse(MODULES["modes"].read_text())
    code = ast.Import | ast.ImportFrom | ast.FunctionDef | ast.ClassDef
    assert not [n for n in ast.walk(tree) if isinstance(n, code)]
    for module, path in MODULES.items():
        if layer(module) == "control":
            assert "inputs" not in {t for t, _, _ in _imports(path)}, module


def test_the_store_depends_on_nothing_but_errors_and_its_records():
    assert {t for t, _, _ in _imports(MODULES["service.store"])} <= {"errors", "service.records"}
    assert {t for t, _, _ in _imports(MODULES["service.records"])} <= {"errors", "inputs", "modes"}


def test_only_the_shell_imports_the_job_queue():
    for module, path in MODULES.items():
        if layer(module) != "cli" and module not in ("__init__", "service.jobs"):
            assert "service.jobs" not in {t for t, _, _ in _imports(path)}, module


def test_no_sql_outside_the_store():
    sql = re.compile(r"\b(SELECT|INSERT INTO|UPDATE \w+ SET|DELETE FROM|CREATE TABLE|PRAGMA)\b")
    offenders = [f"{m}: {line.strip()}" for m, p in MODULES.items() if m != "service.store"
                 for line in p.read_text().splitlines() if sql.search(line)]
    assert offenders == []


def test_imports_inside_functions_are_only_the_shells_lazy_heavy_ones():
    """An import inside a function must have a reason: each CLI verb imports what it uses when it runs
    (MuJoCo, numba, scipy, pycma, dask, matplotlib: ~4 s), so that the parser and the verbs that only read
    the store start at once, and ``query`` reads a run's task and curve (MuJoCo, scipy) only when asked for
    them. Anywhere else it would hide a cycle or a wrong-way edge. ``cli.launch`` (and ``cli.main``) import
    the commands inside ``main`` so that a Ctrl-C during start-up is handled. (tests/cli/test_cli.py checks
    what the verbs load.)"""
    lazy = {(m, t) for m, p in MODULES.items() for t, _, inside in _imports(p) if inside}
    assert {(m, t) for m, t in lazy if m != "cli.commands"} <= {
        ("service.query", "motion.curve"), ("service.query", "motion.taskfile"), ("cli.launch", "cli.commands"),
        ("cli", "cli.commands")}


#: The size limits of a function in cmrt/ (issue 28): lines from ``def`` to its last line, and arguments
#: (``self`` and ``*args``/``**kwargs`` count).
MAX_FUNCTION_LINES = 80
MAX_FUNCTION_ARGS = 15

#: The functions still over a limit, with their sizes when last measured: a ratchet. A function not here must
#: keep within the limits; one here must not grow, and when it shrinks or is split its entry is lowered or
#: removed (the test fails on a stale entry), so the table only shrinks.
STILL_TOO_BIG: dict[str, tuple[int, int]] = {}  # none left: an entry may only be lowered or removed


def _function_sizes() -> dict[str, tuple[int, int]]:
    """``module:qualname`` -> (lines, arguments) of every function and method in cmrt/."""
    sizes = {}

    def walk(node: ast.AST, module: str, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                a = child.args
                n_args = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) \
                    + (a.kwarg is not None)
                sizes[f"{module}:{prefix}{child.name}"] = (child.end_lineno - child.lineno + 1, n_args)
                walk(child, module, f"{prefix}{child.name}.")
            elif isinstance(child, ast.ClassDef):
                walk(child, module, f"{prefix}{child.name}.")
            else:
                walk(child, module, prefix)

    for module, path in MODULES.items():
        walk(ast.parse(path.read_text()), module, "")
    return sizes


def test_no_function_is_too_long_or_takes_too_many_arguments():
    """No function over 80 lines, none with more than 15 arguments (a compiled one included), but those
    still in ``STILL_TOO_BIG``, which may not grow."""
    sizes = _function_sizes()
    too_big = {name: size for name, size in sizes.items()
               if size[0] > MAX_FUNCTION_LINES or size[1] > MAX_FUNCTION_ARGS}
    grown = {name: (size, STILL_TOO_BIG.get(name)) for name, size in too_big.items()
             if name not in STILL_TOO_BIG or size[0] > STILL_TOO_BIG[name][0] or size[1] > STILL_TOO_BIG[name][1]}
    assert grown == {}, "over the limits (size, allowed): split it or group its arguments"


def test_the_table_of_functions_still_too_big_is_not_stale():
    """An entry of ``STILL_TOO_BIG`` whose function shrank, was split or is gone is lowered or removed."""
    sizes = _function_sizes()
    stale = {name: (allowed, sizes.get(name)) for name, allowed in STILL_TOO_BIG.items()
             if sizes.get(name) != allowed
             or (sizes[name][0] <= MAX_FUNCTION_LINES and sizes[name][1] <= MAX_FUNCTION_ARGS)}
    assert stale == {}, "lower or remove these entries (recorded, measured now)"


def test_tools_use_the_api_not_the_cli_or_private_names():
    """``tools/`` are scripts like a user's: they import public names (no underscore) and never the CLI's
    module, whose helpers are parsing and printing (what a script wants is in the API). The one exception
    documents the CLI itself: ``cli_reference.py`` writes docs/reference/cli.md from the parser."""
    tools = Path(__file__).resolve().parent.parent / "tools"
    wrong = []
    for path in sorted(tools.glob("*.py")):
        if path.name == "cli_reference.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "cmrt":
                if node.module.split(".")[:2] == ["cmrt", "cli"] or any(a.name.startswith("_") for a in node.names):
                    wrong.append(f"{path.name}: from {node.module} import {', '.join(a.name for a in node.names)}")
            elif isinstance(node, ast.Import):
                wrong += [f"{path.name}: import {a.name}" for a in node.names if a.name.startswith("cmrt.cli")]
    assert wrong == []
