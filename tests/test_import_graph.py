"""The core's import graph has no cycles and follows the data flow of docs/architecture.md.

Edges are the imports a module makes at module level, including those under
``if TYPE_CHECKING:`` (a cycle through type hints is still a cycle in the design).
Imports inside functions are deferred on purpose and are not edges.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = "mbus_framework"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE

# Layers in the order data flows; a module may import its own layer and layers to its left.
LAYERS = [
    "interfaces",
    "engine",
    "compensation",
    "estimation",
    "pipeline",
    "studies",
    "campaigns",
    "analysis",
]
# Top-level helpers every layer may use (they import nothing from the layers).
FOUNDATION = {"errors", "suggest", "__init__"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _top_level_imports(tree: ast.Module):
    """Import nodes at module level, including inside ``if TYPE_CHECKING`` and try blocks."""
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If):
            stack.extend(node.body + (node.orelse if not _is_type_checking(node.test) else []))
        elif isinstance(node, ast.Try):
            stack.extend(node.body + node.orelse + node.finalbody)
            for handler in node.handlers:
                stack.extend(handler.body)


def _resolve(node: ast.ImportFrom | ast.Import, importer: str, is_package: bool, modules: set[str]):
    if isinstance(node, ast.Import):
        targets = [alias.name for alias in node.names]
    else:
        if node.level:
            base = importer.split(".")
            base = base if is_package else base[:-1]
            base = base[: len(base) - (node.level - 1)]
            prefix = ".".join(base + ([node.module] if node.module else []))
        else:
            prefix = node.module or ""
        targets = [f"{prefix}.{alias.name}" for alias in node.names] + [prefix]
    for target in targets:
        # 'from pkg import module' names the module; 'from module import name' names the module.
        while target and target not in modules:
            target = target.rpartition(".")[0]
        if target and target.startswith(PACKAGE):
            yield target


def import_graph() -> dict[str, set[str]]:
    files = {module_name(p): p for p in ROOT.rglob("*.py")}
    modules = set(files)
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_package = path.name == "__init__.py"
        edges = {t for node in _top_level_imports(tree) for t in _resolve(node, name, is_package, modules)}
        # A package's own __init__ is imported first by every submodule; it is not an edge.
        graph[name] = {e for e in edges if e != name and not name.startswith(e + ".")}
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    cycles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
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
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def test_finds_a_cycle_when_there_is_one():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert find_cycles({"a": {"b"}, "b": set()}) == []


def test_resolves_relative_and_package_imports():
    modules = {"mbus_framework", "mbus_framework.pipeline", "mbus_framework.pipeline.run",
               "mbus_framework.pipeline.config", "mbus_framework.errors"}
    node = ast.parse("from .config import RunConfig\nfrom ..errors import ConfigError").body
    found = {t for n in node for t in _resolve(n, "mbus_framework.pipeline.run", False, modules)}
    assert found == {"mbus_framework.pipeline.config", "mbus_framework.errors"}


def test_core_has_no_import_cycles():
    cycles = find_cycles(import_graph())
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_layers_only_import_upstream():
    wrong = []
    for module, edges in import_graph().items():
        here = layer_of(module)
        if here is None:
            continue
        for target in edges:
            there = layer_of(target)
            if there is not None and LAYERS.index(there) > LAYERS.index(here):
                wrong.append(f"{module} -> {target}")
    assert not wrong, "imports against the data flow: " + ", ".join(sorted(wrong))


#: The engine's one large module, exempt from the 500-line rule (issue 17; simulation.py was split).
ENGINE_EXEMPT = {"engine/chain.py"}


def test_no_core_module_outside_the_engine_is_over_500_lines():
    """Every module of mbus_framework (every subpackage and the top level) but the engine's
    chain assembly."""
    long = [f"{rel}: {n}" for p in sorted(ROOT.rglob("*.py"))
            if (rel := p.relative_to(ROOT).as_posix()) not in ENGINE_EXEMPT
            and (n := len(p.read_text(encoding="utf-8").splitlines())) > 500]
    assert not long, long


def test_no_module_only_aliases_another():
    """Plugin authors import one module, :mod:`mbus_framework.plugins`; no module is a
    ``sys.modules`` alias of another (issue 29)."""
    aliases = [p.relative_to(ROOT).as_posix() for p in ROOT.rglob("*.py") if "sys.modules[__name__]" in p.read_text()]
    assert not aliases, aliases
