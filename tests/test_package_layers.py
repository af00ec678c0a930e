"""No package imports one above it (docs/design.md, "The rule of the layers"), and there is no import cycle: between
packages, nor between modules.

Every ``import`` of every module is read with :mod:`ast`, those inside functions and under ``TYPE_CHECKING``
included (a lazy import is still a dependency, and a type named from above is still a design above), and mapped to
its unit: a subpackage (``bop_cender.data``) or a top-level module (``bop_cender.results``,
``bop_cender.datasets``). The rules name what each unit must never import. Inside every package, the modules form
no circle either (:func:`module_graph`): data types live in their own modules, below the code that uses them, and
kernels below the code that calls them.
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


def module_graph(root: Path = ROOT, packages: tuple[str, ...] = ("bop_cender", "bop_toolkit_adapters")) -> dict:
    """Module -> the modules of ours it imports (:data:`ROOT`'s ``packages``; every import statement, lazy ones and
    those under ``TYPE_CHECKING`` included). ``from package import name`` imports the module ``package.name`` where
    that is a module, else ``package`` itself (its ``__init__``): a package is initialised before any of its modules,
    so that is no edge of its own."""
    paths = {_module_name_under(root, path): path for package in packages for path in (root / package).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in paths.items():
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name in paths}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:
                    target = f"{node.module}.{alias.name}"
                    deps.add(target if target in paths else node.module)
        graph[name] = {d for d in deps if d in paths and d != name}
    return graph


def _module_name_under(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The circles of ``graph``: each strongly connected set of two or more modules, sorted (Tarjan's algorithm,
    without recursion)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, deps = work[-1]
            for dep in deps:
                if dep not in index:
                    index[dep] = low[dep] = len(index)
                    stack.append(dep)
                    on_stack.add(dep)
                    work.append((dep, iter(sorted(graph[dep]))))
                    break
                if dep in on_stack:
                    low[node] = min(low[node], index[dep])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    members = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        members.append(member)
                        if member == node:
                            break
                    if len(members) > 1:
                        found.append(sorted(members))
    return sorted(found)


def test_no_import_cycle_between_modules() -> None:
    """Inside ``pose/``, ``render/``, ``eval/``, ``synth/`` and every other package (and across them): no circle."""
    graph = module_graph()
    assert {"bop_cender.pose.backend", "bop_cender.render.cuda_render", "bop_cender.synth.demo"} <= set(graph)
    circles = import_cycles(graph)
    assert not circles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in circles)


def test_a_circle_through_a_lazy_or_type_checking_import_is_found(tmp_path: Path) -> None:
    """What the test above would say of a circle reintroduced as the known ones were: a kernel that names the type of
    the module that calls it lazily (pose/coverage -> cuda_window_kernel -> scene_polish -> coverage)."""
    package = tmp_path / "bop_cender" / "pose"
    package.mkdir(parents=True)
    (tmp_path / "bop_cender" / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "coverage.py").write_text("def cost():\n    from bop_cender.pose import kernel\n")
    (package / "kernel.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from bop_cender.pose.polish import Window\n"
    )
    (package / "polish.py").write_text("from bop_cender.pose.coverage import cost\nclass Window: ...\n")
    (package / "alone.py").write_text("import bop_cender.pose.polish\nfrom bop_cender.pose import Missing\n")
    graph = module_graph(tmp_path, ("bop_cender",))
    assert graph["bop_cender.pose.alone"] == {"bop_cender.pose.polish", "bop_cender.pose"}
    assert import_cycles(graph) == [["bop_cender.pose.coverage", "bop_cender.pose.kernel", "bop_cender.pose.polish"]]
    (package / "kernel.py").write_text("")  # the type in a module of its own: no circle
    assert import_cycles(module_graph(tmp_path, ("bop_cender",))) == []
