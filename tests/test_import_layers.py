"""The subpackages of meshadv import each other without cycles, the modules inside each subpackage import each other
without cycles, and the layering rules hold.

Read from the source (every ``import`` and ``from ... import``, also inside functions), so a lazy import that would
close a cycle is caught too.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path
from typing import Dict, Set

import meshadv

ROOT = Path(meshadv.__file__).parent
#: Modules at the package's top level that only start things (they may import anything).
ENTRY_POINTS = {"__main__", "cli"}


def _unit(rel: Path) -> str:
    """The subpackage (or top-level module) a file belongs to."""
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _imports(path: Path) -> Set[str]:
    rel = path.relative_to(ROOT)
    package = ["meshadv", *rel.parts[:-1]]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            name = ".".join([*base, node.module] if node.module else base) if node.level else (node.module or "")
            out.add(name)
        elif isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
    return {m for m in out if m.startswith("meshadv.") or m == "meshadv"}


def _graph() -> Dict[str, Set[str]]:
    graph: Dict[str, Set[str]] = defaultdict(set)
    for path in ROOT.rglob("*.py"):
        unit = _unit(path.relative_to(ROOT))
        for module in _imports(path):
            parts = module.split(".")
            if len(parts) > 1 and parts[1] != unit:
                graph[unit].add(parts[1])
    return graph


def test_no_import_cycle_between_subpackages() -> None:
    graph = _graph()
    for entry in ENTRY_POINTS:
        graph.pop(entry, None)
    state: Dict[str, int] = {}

    def visit(node: str, stack: list) -> None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if nxt in ENTRY_POINTS:
                raise AssertionError(f"{node} imports the entry point {nxt}")
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt):] + [nxt] if nxt in stack else [node, nxt]
                raise AssertionError(f"import cycle: {' -> '.join(cycle)}")
            if nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = ["meshadv", *rel.parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _find_cycle(graph: Dict[str, Set[str]]) -> list:
    """One import cycle of ``graph`` (a list of nodes, the first repeated at the end), ``[]`` when there is none."""
    state: Dict[str, int] = {}
    for start in sorted(graph):
        if start in state:
            continue
        stack = [(start, iter(sorted(graph.get(start, ()))))]
        path = [start]
        state[start] = 1
        while stack:
            node, children = stack[-1]
            nxt = next(children, None)
            if nxt is None:
                state[node] = 2
                stack.pop()
                path.pop()
            elif state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            elif nxt not in state:
                state[nxt] = 1
                stack.append((nxt, iter(sorted(graph.get(nxt, ())))))
                path.append(nxt)
    return []


def _module_graph(package: Path) -> Dict[str, Set[str]]:
    """Imports between the modules of one subpackage (its ``__init__`` left out: it only gathers the public names),
    read from the source, also inside functions and under ``TYPE_CHECKING``."""
    modules = {_module_name(p): p for p in package.rglob("*.py") if p.name != "__init__.py"}
    graph: Dict[str, Set[str]] = {m: set() for m in modules}
    for name, path in modules.items():
        for imported in _imports(path):
            while imported and imported not in modules:
                imported = imported.rpartition(".")[0]
            if imported and imported != name:
                graph[name].add(imported)
    return graph


def test_no_import_cycle_inside_any_subpackage() -> None:
    packages = sorted(p.parent for p in ROOT.glob("*/__init__.py"))
    assert len(packages) >= 8
    cycles = {p.name: _find_cycle(_module_graph(p)) for p in packages}
    assert {k: v for k, v in cycles.items() if v} == {}


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) == []


def test_layering_rules() -> None:
    graph = _graph()
    assert not graph["experiments"] & {"transfer", "commands", "study"}, graph["experiments"]
    assert "scenes" not in graph["victims"], graph["victims"]
    assert "datasets" not in graph["victims"] and not (ROOT / "victims" / "rendering_set.py").exists()
    assert graph.get("util", set()) == set(), "meshadv.util must be a leaf"
    assert not (ROOT / "experiments" / "__main__.py").exists()


def test_the_checker_sees_relative_and_lazy_imports(tmp_path: Path) -> None:
    """The parser resolves ``from ..x import y`` and imports inside functions (it would not miss a cycle)."""
    imports = _imports(ROOT / "render" / "camera.py")
    assert "meshadv.util.spherical" in imports
    assert "meshadv.experiments.report" in _imports(ROOT / "commands" / "report.py")  # inside a function
