"""The house (docs/architecture.md): layers that import only downward, no cycles, no paper names.

Reads every module of the package with :mod:`ast` (nothing is imported), so an import inside a
function counts as much as one at the top. Layers, lowest first::

    errors, files, units < robot < mechanics < batch < elastic < workspace < calibration
    < planning, machining < papers < viewer < cli

``stiffness/__init__.py`` (the public API) may import anything; below it, a module imports only
from its own layer or lower ones, and only ``cli`` imports the top package (``__version__``).
The layers below ``papers`` carry no paper-specific name (sk120, table<N>, appendix) in their
module names, identifiers or in a string that is such a name on its own (a key, a preset).
Across the whole package no function is longer than :data:`MAX_FUNCTION_LINES` lines and no
module than :data:`MAX_MODULE_LINES` (a long workflow is a few named steps).
"""

from __future__ import annotations

import ast
import functools
import re
import subprocess
import sys
from pathlib import Path

import stiffness

PACKAGE = Path(stiffness.__file__).resolve().parent

#: Layer of each top-level part of the package, lowest first (see docs/architecture.md).
LAYERS = {
    "errors": 0, "files": 0, "cores": 0, "robots": 0, "htmlpage": 0, "provenance": 0,
    "figures": 0,
    "units": 0,
    "robot": 1,
    "mechanics": 2,
    "batch": 3,
    "elastic": 4,
    "workspace": 5,
    "calibration": 6,
    "planning": 7, "machining": 7,
    "papers": 8,
    "viewer": 9,
    "cli": 10, "__main__": 10,
}
#: Layers that must not know about a paper.
GENERAL = {name for name, layer in LAYERS.items() if layer < LAYERS["papers"]}
#: A paper-specific name: the SK120 of Alici & Shirinzadeh, its tables, its appendix.
PAPER_NAME = re.compile(r"sk[_-]?120|table_?(\d+|i{1,3}v?|iv|v)(?![a-z])|appendix", re.IGNORECASE)


def _module_name(path: Path) -> str:
    parts = ("stiffness",) + path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@functools.cache
def _modules() -> dict[str, tuple[Path, ast.Module]]:
    """Every module of the package: its file and syntax tree (read when a test first asks,
    not at collection: each test process collects this file, one runs its tests)."""
    return {_module_name(p): (p, ast.parse(p.read_text(), filename=str(p)))
            for p in sorted(PACKAGE.rglob("*.py"))}


def _is_package(name: str) -> bool:
    return _modules().get(name, (Path(),))[0].name == "__init__.py"


def _imports(name: str, tree: ast.Module) -> set[str]:
    """Modules of the package that ``name`` imports (anywhere in its file)."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base[: len(base) - node.level + (1 if _is_package(name) else 0)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                out.add(sub if sub in _modules() else target)
    return {m for m in out if m == "stiffness" or m.startswith("stiffness.")}


@functools.cache
def _package_imports() -> dict[str, set[str]]:
    """:func:`_imports` of every module of the package (read-only)."""
    return {name: _imports(name, tree) for name, (_, tree) in _modules().items()}


def _layer(module: str) -> int:
    part = module.split(".")[1]
    if part not in LAYERS:
        raise AssertionError(f"{module} belongs to no layer: add it to docs/architecture.md and "
                             "to LAYERS in this test")
    return LAYERS[part]


def _cycles() -> list[list[str]]:
    """Strongly connected components (Tarjan) of more than one module, or self-imports."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(_package_imports().get(v, ())):
            if w not in _modules():
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in _package_imports().get(v, ()):
                found.append(sorted(component))

    for v in sorted(_modules()):
        if v not in index:
            visit(v)
    return found


def _layer_violations() -> set[tuple[str, str, str]]:
    out = set()
    for module, targets in _package_imports().items():
        if module == "stiffness":
            continue
        for target in targets:
            if target == "stiffness":
                if _layer(module) != LAYERS["cli"]:
                    out.add((module, "import", target))
            elif target in _modules() and _layer(target) > _layer(module):
                out.add((module, "import", target))
    return out


def _cycle_violations() -> set[tuple[str, str, str]]:
    return {(c[0], "cycle", " <-> ".join(c)) for c in _cycles()}


def _identifiers(tree: ast.Module) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
        elif isinstance(node, ast.alias):
            names.add(node.asname or node.name.split(".")[-1])
        elif isinstance(node, ast.keyword) and node.arg:
            names.add(node.arg)
    return names


def _name_strings(tree: ast.Module) -> set[str]:
    """String constants that are a paper name on their own (a key, a preset, a robot name)."""
    return {node.value.strip().lower() for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and PAPER_NAME.fullmatch(node.value.strip())}


def _paper_name_violations() -> set[tuple[str, str, str]]:
    out = set()
    for module, (path, tree) in _modules().items():
        if module == "stiffness" or _layer(module) not in {LAYERS[g] for g in GENERAL}:
            continue
        if PAPER_NAME.search(path.relative_to(PACKAGE).as_posix()):
            out.add((module, "module", path.name))
        out |= {(module, "name", n) for n in _identifiers(tree) if PAPER_NAME.search(n)}
        out |= {(module, "string", s) for s in _name_strings(tree)}
    return out


#: Longest function allowed, in lines from its ``def`` to its last line (docstring included).
MAX_FUNCTION_LINES = 100
#: Longest module allowed, in lines.
MAX_MODULE_LINES = 800


def _function_lengths(tree: ast.Module) -> dict[str, int]:
    """Length in lines of every function and method of a module (``Class.method`` names)."""
    out: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                out[name] = max(out.get(name, 0), child.end_lineno - child.lineno + 1)
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(tree, "")
    return out


def _size_violations() -> set[tuple[str, str, int]]:
    """(module, what, lines) of every module and function over its limit, package-wide."""
    out: set[tuple[str, str, int]] = set()
    for module, (path, tree) in _modules().items():
        lines = len(path.read_text().splitlines())
        if lines > MAX_MODULE_LINES:
            out.add((module, "module", lines))
        out |= {(module, f"function {name}", n) for name, n in _function_lengths(tree).items()
                if n > MAX_FUNCTION_LINES}
    return out


# ------------------------------------------------------------------------------------ tests


def test_every_module_belongs_to_a_layer():
    for module in _modules():
        if module != "stiffness":
            _layer(module)


def test_the_reader_sees_the_imports_it_must():
    """The checks below are only as good as the import reader: it finds known edges."""
    imports = _package_imports()
    assert "stiffness.robot.robot" in imports["stiffness.mechanics.formulation"]
    assert "stiffness.robot.kinematics" in imports["stiffness.mechanics.platform"]
    assert "stiffness.viewer" in imports["stiffness.cli.report"]
    assert {"stiffness.robot.robot", "stiffness.mechanics.formulation"} <= imports["stiffness"]
    # a lazy import inside a function counts
    lazy = ast.parse("def f():\n    from stiffness.viewer import StiffnessViewer\n")
    assert _imports("stiffness.robot.robot", lazy) == {"stiffness.viewer"}


def test_no_import_from_a_higher_layer():
    found = _layer_violations()
    assert not found, "imports from a higher layer: " + "; ".join(
        f"{m} imports {t}" for m, _, t in sorted(found))


def test_no_import_cycles():
    found = _cycle_violations()
    assert not found, "import cycles: " + "; ".join(c for _, _, c in sorted(found))


def test_no_paper_names_below_papers():
    found = _paper_name_violations()
    assert not found, "paper-specific names below `papers`: " + "; ".join(
        f"{m}: {kind} {n!r}" for m, kind, n in sorted(found))


def test_no_long_function_or_module():
    """Every module of the package: no function over 100 lines, no module over 800."""
    found = _size_violations()
    assert not found, "too long (split into named steps or focused modules): " + "; ".join(
        f"{m}: {what} has {n} lines" for m, what, n in sorted(found))


def test_the_checks_catch_what_they_forbid(tmp_path):
    """Each rule fails on a module written to break it (the rules can fail)."""
    tree = ast.parse("from stiffness.papers.sk120 import read_table1\n"
                     "def _is_sk120(robot):\n    return robot.name == 'sk120'\n")
    assert "stiffness.papers.sk120" in _imports("stiffness.robot.bad", tree)
    assert {"_is_sk120"} <= {n for n in _identifiers(tree) if PAPER_NAME.search(n)}
    assert _name_strings(tree) == {"sk120"}
    relative = ast.parse("from ..papers import report\nfrom . import robot\n")
    assert _imports("stiffness.robot.loops", relative) == {"stiffness.papers.report",
                                                            "stiffness.robot.robot"}
    assert not PAPER_NAME.search("stable_definiteness") and PAPER_NAME.search("TABLE_IV")
    lines = "".join(f"        x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES - 1))
    long = ast.parse("class C:\n    def m(self):\n" + lines
                     + "def f():\n" + lines.replace("        ", "    ") + "    return 0\n")
    assert _function_lengths(long) == {"C.m": MAX_FUNCTION_LINES, "f": MAX_FUNCTION_LINES + 1}


# ------------------------------------------------------------------------ the public API


def test_the_package_top_exports_every_layer():
    """``stiffness.__all__`` resolves, each entry documented, every layer represented."""
    layers = set()
    for name in stiffness.__all__:
        value = getattr(stiffness, name)
        if name == "__version__":
            assert isinstance(value, str) and value
            continue
        assert (value.__doc__ or "").strip(), f"stiffness.{name} has no docstring"
        layers.add(value.__module__.split(".")[1])
    assert {"robot", "mechanics", "batch", "elastic", "workspace", "calibration", "planning",
            "machining", "papers", "viewer"} <= layers
    assert set(stiffness.__all__) <= set(dir(stiffness))


def test_the_package_top_exports_every_error_and_warning():
    """Every :class:`~stiffness.errors.StiffnessError` subclass and every warning class the
    package defines is in ``stiffness.__all__`` (a user catches what the package raises without
    knowing its modules)."""
    import importlib
    import pkgutil

    from stiffness.errors import StiffnessError

    missing = set()
    for info in pkgutil.walk_packages(stiffness.__path__, "stiffness."):
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if (isinstance(value, type) and value.__module__ == module.__name__
                    and issubclass(value, (StiffnessError, Warning))
                    and not name.startswith("_")):
                missing |= {f"{module.__name__}.{name}"} - {
                    f"{module.__name__}.{n}" for n in stiffness.__all__}
    assert not missing, f"errors and warnings missing from stiffness.__all__: {sorted(missing)}"


def test_importing_the_package_stays_light():
    """``import stiffness`` (every command does) loads no optimiser, plotting or viewer."""
    heavy = ("scipy.optimize", "matplotlib", "meshcat", "stiffness.calibration.identify",
             "stiffness.viewer")
    code = f"import sys, stiffness; print(' '.join(m for m in {heavy!r} if m in sys.modules))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True).stdout.split()
    assert not loaded, f"import stiffness loads {loaded}"


def test_every_package_is_in_the_wheel():
    """Every folder of ``stiffness/`` holding an ``__init__.py`` is listed in pyproject.toml's
    ``[tool.setuptools] packages`` (a missing one leaves a non-editable install without it;
    tests/test_wheel.py builds the wheel, this is the quick check)."""
    from stiffness.files import read_toml

    root = Path(__file__).resolve().parents[1]
    listed = set(read_toml(root / "pyproject.toml")["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(root).parts)
             for p in (root / "stiffness").rglob("__init__.py")}
    assert found - listed == set(), f"packages missing from pyproject.toml: {found - listed}"
