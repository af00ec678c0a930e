"""No package imports one above it (docs/design.md, "The rule of the layers"), and there is no import cycle.

Every ``import`` of every module is read with :mod:`ast`, those inside functions included (a lazy import is
still a dependency), and mapped to its unit: a subpackage (``bop_cender.data``) or a top-level module
(``bop_cender.results``, ``bop_cender.datasets``). The rules name what each unit must never import.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The method's modules: scoring and the data layer never import them.
METHOD = {"net", "centers", "pose", "method", "runner", "estimates_io"}
#: Units above the libraries: only the command line (and each other, downwards) import them.
APPS = {"cli", "datasets", "regression"}

NEVER = {
    "geometry": {"data", "render", "synth", "eval", "results", "report"} | METHOD | APPS,
    "data": {"render", "synth", "eval", "results", "report"} | METHOD | APPS,
    "render": {"synth", "eval", "results", "report"} | METHOD | APPS,
    "synth": {"eval", "report"} | METHOD | APPS,
    "results": {"render", "synth", "eval", "report"} | METHOD | APPS,
    "eval": {"synth", "report"} | METHOD | APPS,
    "report": {"synth"} | METHOD | APPS,
    "bop_toolkit_adapters": {"synth"} | METHOD | APPS,
    "visibility": {"data", "synth", "eval", "results", "report"} | METHOD | APPS,
    "meshes": {"synth", "eval", "results", "report"} | METHOD | APPS,
    # the optimisers of stages 2 and 3 (lockstep Nelder-Mead): below both, so they import nothing of the project
    "optim": {"geometry", "data", "render", "synth", "eval", "results", "report", "visibility", "meshes"}
    | METHOD
    | APPS,
}


def _unit(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] == "bop_toolkit_adapters":
        return "bop_toolkit_adapters"
    if parts[0] != "bop_cender" or len(parts) < 2:
        return None
    return parts[1]


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_graph() -> dict[str, dict[str, set[str]]]:
    """unit -> imported unit -> the modules of ``unit`` that import it."""
    graph: dict[str, dict[str, set[str]]] = {}
    for package in ("bop_cender", "bop_toolkit_adapters"):
        for path in sorted((ROOT / package).rglob("*.py")):
            name = _module_name(path)
            unit = _unit(name)
            if unit is None:
                continue
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                targets = []
                if isinstance(node, ast.Import):
                    targets = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
                for target in targets:
                    other = _unit(target)
                    if other is not None and other != unit and not (target == "bop_cender" and not other):
                        graph.setdefault(unit, {}).setdefault(other, set()).add(name)
    return graph


def test_no_package_imports_one_above_it() -> None:
    graph = import_graph()
    found = [
        f"{unit} imports {other} ({', '.join(sorted(where))})"
        for unit, never in NEVER.items()
        for other, where in graph.get(unit, {}).items()
        if other in never
    ]
    assert not found, "\n".join(found)


def test_no_import_cycle_between_packages() -> None:
    graph = {u: set(deps) for u, deps in import_graph().items()}
    # errors.py is the shared leaf every unit may import (typed errors); it imports nothing of ours
    assert not graph.get("errors"), graph.get("errors")
    state: dict[str, int] = {}

    def visit(unit: str, path: list[str]) -> None:
        state[unit] = 1
        for other in sorted(graph.get(unit, ())):
            assert state.get(other) != 1, "import cycle: " + " -> ".join([*path, unit, other])
            if other not in state:
                visit(other, [*path, unit])
        state[unit] = 2

    for unit in sorted(graph):
        if unit not in state:
            visit(unit, [])


def test_the_data_layer_prints_nothing() -> None:
    for path in sorted((ROOT / "bop_cender" / "data").rglob("*.py")):
        calls = [
            n.lineno
            for n in ast.walk(ast.parse(path.read_text()))
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "print"
        ]
        assert not calls, f"{path.name}: print() on lines {calls}"
