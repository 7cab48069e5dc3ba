"""The import graph of the project's packages: no import loop and no upward import (issue 22).

The graph is read from the source with :mod:`ast` (nothing is imported): a node per module of
``sim``, ``fusion`` and ``scenes``, an edge ``a -> b`` where ``a`` imports ``b`` (``import b``,
``from b import name``, ``from b.c import name`` -> the module ``b.c``, ``from b import c`` -> the
module ``b.c`` where ``c`` is one, relative imports resolved against ``a``'s package).

What counts as an import:

- Every ``import`` statement, at a module's top level *and* inside a function: a function-level
  import is a deferred import, and a loop through one is still a loop (the known
  ``sim.noise`` <-> ``sim.radiometry`` loop existed only through a function-level import, and
  ``fusion.methods`` -> ``fusion.fill.dense`` was one too). Both checks use the same graph.
- Not counted: imports under ``if TYPE_CHECKING:`` (never run), and the implicit import of a
  parent package (importing ``fusion.fill.dense`` runs ``fusion/__init__.py``, which re-exports the
  package's modules; counting that would make every package a loop by construction).

The layering: ``sim`` makes the data (rendering, events, sequences), ``fusion`` consumes it
(mapping, filling, scoring), ``scenes`` holds scene files. So neither ``sim`` nor ``scenes``
may import ``fusion``.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("sim", "fusion", "scenes")
LOWER = ("sim", "scenes")        # packages that must not import UPPER
UPPER = ("fusion",)


def _modules() -> dict[str, Path]:
    """Dotted module name -> source file, for every module of :data:`PACKAGES`."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def _import_nodes(tree: ast.AST):
    """Every Import / ImportFrom node of ``tree`` (any depth), less ``if TYPE_CHECKING:`` ones."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                stack.extend(child.orelse)
                continue
            stack.append(child)


def _targets(name: str, path: Path, node: ast.Import | ast.ImportFrom,
             modules: dict[str, Path]) -> set[str]:
    """The project modules that ``node`` (in module ``name`` at ``path``) imports."""
    if isinstance(node, ast.Import):
        wanted = [alias.name for alias in node.names]
    else:
        base = node.module or ""
        if node.level:
            package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
            package = package[:len(package) - (node.level - 1)]
            base = ".".join(package + ([base] if base else []))
        wanted = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                  for alias in node.names]
    found = set()
    for target in wanted:
        while target and target not in modules:       # a name inside a module: the module
            target = target.rpartition(".")[0]
        if target and target != name:
            found.add(target)
    return found


def import_graph() -> dict[str, dict[str, int]]:
    """``graph[a][b]`` = the first line at which module ``a`` imports project module ``b``."""
    modules = _modules()
    graph: dict[str, dict[str, int]] = {name: {} for name in modules}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in _import_nodes(tree):
            for target in _targets(name, path, node, modules):
                line = graph[name].get(target, node.lineno)
                graph[name][target] = min(line, node.lineno)
    return graph


def _loops(graph: dict[str, dict[str, int]]) -> list[set[str]]:
    """The strongly connected components with more than one module or a self-loop: the sets of
    modules that import each other (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    if len(component) > 1 or node in graph[node]:
                        components.append(component)
    return components


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """One cycle (``[a, b, ..., a]``) per loop of :func:`_loops`."""
    return [_one_cycle(graph, component) for component in _loops(graph)]


def _one_cycle(graph: dict[str, dict[str, int]], component: set[str]) -> list[str]:
    """A shortest cycle through the component's first module, by breadth-first search."""
    start = min(component)
    previous = {start: None}
    queue = [start]
    while queue:
        node = queue.pop(0)
        for child in sorted(graph[node]):
            if child == start:
                path = [node]
                while previous[path[-1]] is not None:
                    path.append(previous[path[-1]])
                return [*reversed(path), start]
            if child in component and child not in previous:
                previous[child] = node
                queue.append(child)
    raise AssertionError(f"no cycle through {start}")          # cannot happen for an SCC


def _describe(graph: dict[str, dict[str, int]], component: set[str]) -> str:
    """A loop in one line: one cycle through it (``module:line`` of each import), then all the
    modules caught in it."""
    cycle = _one_cycle(graph, component)
    steps = " -> ".join(f"{a}:{graph[a][b]}" for a, b in zip(cycle, cycle[1:], strict=False))
    return f"{steps} -> {cycle[-1]}  (the loop holds {', '.join(sorted(component))})"


def _upward(graph: dict[str, dict[str, int]]) -> list[str]:
    """Every import of an :data:`UPPER` module by a :data:`LOWER` one, ``a imports b (line N)``."""
    return [f"{a} imports {b} (line {line})"
            for a, targets in sorted(graph.items()) if a.split(".")[0] in LOWER
            for b, line in sorted(targets.items()) if b.split(".")[0] in UPPER]


def test_graph_sees_the_project():
    """The reader finds the modules and edges it must (so that an empty graph cannot pass)."""
    graph = import_graph()
    assert {"sim.noise", "sim.radiometry", "sim.validation", "fusion.methods", "fusion.fill.dense",
            "fusion.methods.baselines", "scenes"} <= set(graph)
    assert "sim.camera" in graph["fusion.fill.dense"]            # a top-level import
    assert "fusion.fill.filling" in graph["fusion.methods.surface_fit"]
    # a function-level import
    assert "sim.capture_errors" in graph["fusion.scoring"]


def test_cycle_finder_on_a_known_graph():
    """The loop finder reports a planted loop and nothing on a chain."""
    chain = {"a": {"b": 1}, "b": {"c": 2}, "c": {}}
    assert _cycles(chain) == []
    looped = {"a": {"b": 1}, "b": {"c": 2}, "c": {"a": 3, "d": 4}, "d": {}}
    assert _cycles(looped) == [["a", "b", "c", "a"]]
    assert _cycles({"a": {"a": 1}}) == [["a", "a"]]
    assert _loops(looped) == [{"a", "b", "c"}]


def test_upward_finder_on_a_known_graph():
    """The upward check reports a planted sim -> fusion edge and not the downward one."""
    graph = {"sim.x": {"fusion.y": 7}, "fusion.y": {"sim.x": 3}, "scenes": {"fusion": 2}}
    assert _upward(graph) == ["scenes imports fusion (line 2)", "sim.x imports fusion.y (line 7)"]
    assert _upward({"fusion.y": {"sim.x": 3}, "sim.x": {}}) == []


def test_no_import_loop():
    """No module of sim, fusion or scenes imports itself through others (top-level and
    function-level imports alike)."""
    graph = import_graph()
    loops = _loops(graph)
    assert not loops, ("import loops (module:line of each import):\n"
                       + "\n".join(_describe(graph, loop) for loop in loops))


def test_no_upward_import():
    """Neither sim nor scenes imports fusion (data-making below data-consuming), at any level."""
    graph = import_graph()
    offending = _upward(graph)
    assert not offending, "upward imports:\n" + "\n".join(offending)
