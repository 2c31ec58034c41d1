"""The subpackages of meshadv import each other without cycles, and the layering rules hold.

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
