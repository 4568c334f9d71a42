"""The package's import graph, read from the source: no cycles, and project imports at module top.

Every ``import``/``from ... import`` of an nhstab module in pipeline/ is an edge; importing
``nhstab.a.b`` also imports the package ``nhstab.a`` (its ``__init__``), so that is an edge too.
Imports under ``if TYPE_CHECKING:`` are not run and are not counted. A lazy package facade
(:mod:`nhstab._lazy`) imports its submodules only when a name is asked for: that is not an edge.
"""
from __future__ import annotations

import ast
from pathlib import Path

PIPELINE = Path(__file__).resolve().parents[1] / "pipeline"

#: the imports of project modules that stay inside a function, each with its reason
DEFERRED = {
    ("nhstab.robot", "nhstab.control.gramian"):
        "control.gramian imports scipy.integrate (heavy); reading a robot file needs only two of its tuples",
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PIPELINE).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(["nhstab", *parts])


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in PIPELINE.rglob("*.py")}


def _targets(module: str, node, is_package: bool, modules) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name in modules]
    if node.level:
        base = module if is_package else module.rsplit(".", 1)[0]
        for _ in range(node.level - 1):
            base = base.rsplit(".", 1)[0]
        target = base + ("." + node.module if node.module else "")
    else:
        target = node.module or ""
    out = []
    for alias in node.names:
        sub = f"{target}.{alias.name}"
        out.append(sub if sub in modules else target)
    return [t for t in out if t in modules]


def _imports():
    """(module-level edges {module: set of modules}, function-level imports [(module, target, line)])."""
    modules = _modules()
    top: dict[str, set] = {m: set() for m in modules}
    inner: list[tuple[str, str, int]] = []
    for module, path in modules.items():
        is_package = path.name == "__init__.py"

        def walk(node, in_function: bool):
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.Import, ast.ImportFrom)):
                    for target in _targets(module, child, is_package, modules):
                        if in_function:
                            inner.append((module, target, child.lineno))
                        else:
                            top[module].add(target)
                elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                    walk(child, True)
                elif isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                    continue
                else:
                    walk(child, in_function)

        walk(ast.parse(path.read_text()), False)
    # importing a submodule runs its parent packages' __init__ first
    for module, targets in top.items():
        for target in list(targets):
            parts = target.split(".")
            for i in range(2, len(parts)):
                package = ".".join(parts[:i])
                if package in modules and not module.startswith(package + ".") and module != package:
                    targets.add(package)
        targets.discard(module)
    return top, inner


def _cycles(graph: dict[str, set]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_graph_is_read_from_every_module():
    top, _ = _imports()
    assert len(top) >= 90
    # spot checks against the source: known edges are found, parent packages included
    assert "nhstab.tubes.base" in top["nhstab.tubes.sampled"]
    assert "nhstab.execution.config" in top["nhstab.tubes.fit"] and "nhstab.execution" in top["nhstab.tubes.fit"]
    assert "nhstab.maps.bundled" in top["nhstab.maps"]


def test_module_level_imports_have_no_cycle():
    top, _ = _imports()
    assert _cycles(top) == []


def test_with_deferred_imports_counted_there_is_still_no_cycle():
    top, inner = _imports()
    graph = {m: set(t) for m, t in top.items()}
    for module, target, _ in inner:
        graph[module].add(target)
    assert _cycles(graph) == []


def test_the_cycle_check_finds_a_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]


def test_project_imports_inside_functions_are_the_documented_ones():
    _, inner = _imports()
    found = {(m, t) for m, t, _ in inner}
    assert found == set(DEFERRED), sorted(inner)
