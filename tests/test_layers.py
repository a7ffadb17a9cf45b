"""The package's import graph, read from the source files (ast, nothing imported): no import
loop among vertebra's modules, the layering of its subpackages, and no function-level import of
a vertebra module without a ``# lazy:`` comment saying why it is not at the top of its module.

Layers (each may import the ones listed, and itself)::

    core      numpy/scipy only: nothing of vertebra
    store     core
    solver    core, store
    designer  core, store (it reads the runtime's scenes as data: its one import of the solver,
              ``Scene`` in ``designer.preparation``, is for type checkers alone)
    cli       anything; nothing imports cli
"""

from __future__ import annotations

import ast
import os
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]       # the repository root is the package `vertebra`
PACKAGE = "vertebra"
SUBPACKAGES = ("cli", "core", "designer", "solver", "store")
ALLOWED = {
    "core": set(),
    "store": {"core"},
    "solver": {"core", "store"},
    "designer": {"core", "store"},
    "cli": {"core", "store", "solver", "designer"},
}
LAZY_MARK = "# lazy:"
#: imports under ``if TYPE_CHECKING:`` that cross the layering (they never run)
TYPE_ONLY_EXCEPTIONS = {("vertebra.designer.preparation", "vertebra.solver.scene")}


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join([PACKAGE, *parts])


def _sources() -> dict[str, pathlib.Path]:
    found = {PACKAGE: ROOT / "__init__.py", f"{PACKAGE}.__main__": ROOT / "__main__.py"}
    for sub in SUBPACKAGES:
        for path in sorted((ROOT / sub).rglob("*.py")):
            found[_module_name(path)] = path
    return found


MODULES = _sources()


class Import:
    """One import of a vertebra module: where it is, whether it runs when the module loads
    (``in_function``: only when the function runs; ``type_only``: under ``if TYPE_CHECKING:``,
    never) and the lines a ``# lazy:`` comment may stand on (the statement's own lines and the
    line above the run of import statements it belongs to)."""

    def __init__(self, source: str, target: str, line: int, in_function: bool, type_only: bool, comment_lines):
        self.source, self.target, self.line = source, target, line
        self.in_function, self.type_only, self.comment_lines = in_function, type_only, comment_lines

    def __repr__(self):
        return f"{self.source}:{self.line} -> {self.target}"


def _resolve(name: str) -> str | None:
    """The vertebra module ``name`` denotes (the longest existing prefix: ``from vertebra.x import y``
    with ``y`` a function names ``vertebra.x``), or None outside vertebra."""
    if name != PACKAGE and not name.startswith(PACKAGE + "."):
        return None
    while name not in MODULES and "." in name:
        name = name.rsplit(".", 1)[0]
    return name


def _is_type_checking(node) -> bool:
    if not isinstance(node, ast.If):
        return False
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING"
            or isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(module: str, path: pathlib.Path) -> list[Import]:
    text = path.read_text()
    lines = text.splitlines()
    tree = ast.parse(text, str(path))
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = []

    def targets(node) -> list[str]:
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[:len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            # `from package import submodule` imports the submodule
            names = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base for alias in node.names]
        return [t for t in map(_resolve, names) if t is not None and t != module]

    def visit(node, in_function: bool, type_only: bool):
        run_start = None            # first line of the run of import statements the current one is in
        for child in ast.iter_child_nodes(node):
            if not isinstance(child, (ast.Import, ast.ImportFrom)):
                run_start = None
                inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
                if _is_type_checking(child):        # its body never runs, its else branch does
                    visit(ast.Module(body=child.body, type_ignores=[]), inner, True)
                    visit(ast.Module(body=child.orelse, type_ignores=[]), inner, type_only)
                else:
                    visit(child, inner, type_only)
                continue
            run_start = child.lineno if run_start is None else run_start
            comment_lines = lines[max(run_start - 2, 0):child.end_lineno]
            for target in targets(child):
                found.append(Import(module, target, child.lineno, in_function, type_only, comment_lines))

    visit(tree, False, False)
    return found


IMPORTS = [imp for module, path in MODULES.items() for imp in _imports(module, path)]


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in SUBPACKAGES else None


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, on_stack, stack, components = {}, {}, set(), [], []

    def strongconnect(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                strongconnect(w)
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
            if len(component) > 1:
                components.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            strongconnect(v)
    return components


def test_the_graph_is_read():
    """The walk finds the subpackages and the imports between them (a broken walk would pass
    every other test here vacuously)."""
    assert {"vertebra.core.errors", "vertebra.designer.segment", "vertebra.solver.model",
            "vertebra.store.catalogue", "vertebra.cli.main"} <= set(MODULES)
    targets = {(imp.source, imp.target) for imp in IMPORTS}
    assert ("vertebra.store.entry", "vertebra.core.errors") in targets or \
        any(src.startswith("vertebra.store") and dst.startswith("vertebra.core") for src, dst in targets)
    assert len(IMPORTS) > 100


@pytest.mark.parametrize("in_functions", [False, True], ids=["module-level", "all"])
def test_no_import_loop(in_functions):
    """No cycle among vertebra's modules, neither through the imports that run when a module
    loads nor once the function-level (lazy) ones are counted too (imports for type checkers
    alone never run)."""
    edges: dict[str, set[str]] = {}
    for imp in IMPORTS:
        if not imp.type_only and (in_functions or not imp.in_function):
            edges.setdefault(imp.source, set()).add(imp.target)
    assert _cycles(edges) == []


def test_layering():
    """Each subpackage imports only the layers below it; nothing but cli (and ``python -m
    vertebra``, its entry point) imports cli. Imports for type checkers alone follow the same
    rule, but for the one the designer's ``prepare`` needs to annotate a runtime scene (the
    designer reads scenes as data, never importing the solver)."""
    wrong = []
    for imp in IMPORTS:
        source, target = _layer(imp.source), _layer(imp.target)
        if target == "cli":
            if source != "cli" and imp.source != f"{PACKAGE}.__main__":
                wrong.append(imp)
            continue
        if source is None or target is None or source == target or target in ALLOWED[source]:
            continue
        if imp.type_only and (imp.source, imp.target) in TYPE_ONLY_EXCEPTIONS:
            continue
        wrong.append(imp)
    assert wrong == []


def test_function_level_imports_say_why():
    """An import of a vertebra module inside a function carries a ``# lazy:`` comment giving the
    reason (on its own lines, or on the line above the run of imports it belongs to); everything
    else is imported at the top of its module."""
    unexplained = [imp for imp in IMPORTS
                   if imp.in_function and not any(LAZY_MARK in line for line in imp.comment_lines)]
    assert unexplained == []


def test_every_subpackage_is_shipped():
    """pyproject.toml lists every package folder of the product (a folder missing there would
    be left out of the wheel, and its imports fail once installed) and no folder that is gone."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    on_disk = {PACKAGE} | {".".join([PACKAGE, *init.parent.relative_to(ROOT).parts])
                           for sub in SUBPACKAGES for init in (ROOT / sub).rglob("__init__.py")}
    assert on_disk - listed == set()
    product = {name for name in listed if name.split(".")[1:2] != ["examples"]}
    assert product - on_disk == set()


def test_the_folders_are_not_importable_as_bare_packages():
    """The tests see vertebra's modules only as ``vertebra.*`` (under ``python -m pytest`` as under
    ``pytest``: conftest.py takes the repository root off ``sys.path``); a bare ``solver`` or
    ``designer`` would be a second copy of the package."""
    import importlib.util

    for name in SUBPACKAGES:
        spec = importlib.util.find_spec(name)
        assert spec is None or not str(spec.origin or "").startswith(str(ROOT) + os.sep), (name, spec.origin)
