"""The import graph of mop_core and the stage scripts: no cycle, and a bounded longest import chain.

Imports under ``if TYPE_CHECKING:`` (annotations only) do not count; function-level imports do.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

from conftest import ROOT, runtime_imports

LONGEST_CHAIN = 10  # modules, stage script included


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] == "stages":
        return f"stages.{parts[-1]}"
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in [*(ROOT / "mop_core").rglob("*.py"), *(ROOT / "stages").glob("*.py")]}


def imports(name: str) -> set[str]:
    """The repository modules ``name`` imports (a package's ``__init__`` when it imports the package)."""
    found = set()
    for node in runtime_imports(ast.parse(MODULES[name].read_text())):
        if isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        else:
            module = node.module or ""
            candidates = [module, *(f"{module}.{alias.name}" for alias in node.names)]
        for candidate in candidates:
            if candidate == "common" and name.startswith("stages."):
                candidate = "stages.common"
            if candidate in MODULES and candidate != name:
                found.add(candidate)
    return found


GRAPH = {name: imports(name) for name in MODULES}


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Every cycle a depth-first walk of ``edges`` meets (empty: the graph is a DAG)."""
    state: dict[str, int] = {}
    found: list[list[str]] = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for other in sorted(edges.get(node, ())):
            if state.get(other) == 1:
                found.append(stack[stack.index(other):] + [node, other] if other in stack else [node, other])
            elif other not in state:
                visit(other, stack + [node])
        state[node] = 2

    for node in sorted(edges):
        if node not in state:
            visit(node, [])
    return found


def test_the_import_graph_has_no_cycle():
    assert not cycles(GRAPH), f"import cycles: {cycles(GRAPH)}"


def test_the_longest_import_chain_is_bounded():
    @cache
    def chain(name: str) -> tuple[str, ...]:
        longest = max((chain(other) for other in GRAPH[name]), key=len, default=())
        return (name, *longest)

    worst = max((chain(name) for name in GRAPH), key=len)
    assert len(worst) <= LONGEST_CHAIN, f"{len(worst)} modules: {' -> '.join(worst)}"


def wing(name: str) -> str:
    """A module's wing: its subpackage of mop_core (``mop_core.distill``), a top-level module itself, or
    ``stages``."""
    parts = name.split(".")
    if parts[0] == "stages":
        return "stages"
    return ".".join(parts[:2]) if len(parts) > 2 or (ROOT / "mop_core" / parts[-1]).is_dir() else name


def test_the_wings_are_layered():
    """No import from a lower wing back up: the graph of wings (subpackages, top-level modules) has no
    cycle, so each wing sits above the ones it imports."""
    edges: dict[str, set[str]] = {}
    for name, imported in GRAPH.items():
        edges.setdefault(wing(name), set()).update(wing(other) for other in imported if wing(other) != wing(name))
    both = sorted((a, b) for a in edges for b in edges[a] if a < b and a in edges.get(b, set()))
    assert not both, f"wings that import each other: {both}"
    assert not cycles(edges), f"wing cycles: {cycles(edges)}"
