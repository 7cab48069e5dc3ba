"""The import graph of the project's packages: no import loop, no upward import, thin command
lines (issues 22 and 35).

The graph is read from the source with :mod:`ast` (nothing is imported): a node per module of
``sim``, ``fusion`` and ``scenes``, an edge ``a -> b`` where ``a`` imports ``b`` (``import b``,
``from b import name``, ``from b.c import name`` -> the module ``b.c``, ``from b import c`` -> the
module ``b.c`` where ``c`` is one, relative imports resolved against ``a``'s package).

What counts as an import:

- Every ``import`` statement, at a module's top level *and* inside a function: a function-level
  import is a deferred import, and a loop through one is still a loop (the known
  ``sim.noise`` <-> ``sim.radiometry`` loop existed only through a function-level import, and
  ``fusion.methods`` -> ``fusion.fill.dense`` was one too). Both checks use the same graph.
- Imports under ``if TYPE_CHECKING:`` too (issue 35). They never run, so a loop through one is
  no runtime loop; but a module that needs a type from a module that imports it shows the type
  living in the wrong module: ``fusion.fill.dense`` defined ``DenseParams``, ``DenseResult`` and
  ``FillInputs`` while ``fusion.io``, ``fusion.scoring``, ``fusion.figures`` and
  ``fusion.methods._registry``, which it imports, took them type-only. They now live below all
  of those (``fusion.fill.records``), and a type-only loop fails here like any other.
- Not counted: the implicit import of a parent package (importing ``fusion.fill.dense`` runs
  ``fusion/__init__.py``, which re-exports the package's modules; counting that would make every
  package a loop by construction).

The layering (:data:`FORBIDDEN`, a table of lower module -> the modules above it that it may not
import, each entry a dotted prefix: ``sim.scene`` is ``sim.scene`` and everything in it):

- ``sim`` makes the data (rendering, events, sequences), ``fusion`` consumes it (mapping,
  filling, scoring), ``scenes`` holds scene files: neither ``sim`` nor ``scenes`` imports
  ``fusion``.
- Inside ``sim``, the layers of :data:`SIM_LAYERS`, from the bottom: the scene model
  (``sim.scene``: the parsed scene, its parser, the procedural scenes), which the renderer reads
  (``sim.render``, with its Mitsuba helpers ``sim.mitsuba_sensor`` and ``sim.variant``); what
  renders through it (``sim.shader``, a rig's frame camera ``sim.two_camera``, ground-truth flow
  ``sim.flow``, the procedural scenes' exact-depth check ``sim.scene_check``); the simulation
  (``sim.simulate``); datasets (``sim.dataset``); the command line (``sim.cli``). A layer may
  import the ones below it, never one above. The slip this catches: the scene model imported
  the renderer (``sim.scene.procedural`` -> ``sim.render``, to check a drawn scene's depth
  range); that check now runs in ``sim.scene_check``, above both. Modules in no layer
  (``sim.camera``, ``sim.trajectory``, ``sim.textures``, ...) are not constrained by it.

The command lines stay thin (:data:`MAX_CLI_LINES`): they only parse, check and call the public
API, so each module of ``sim`` or ``fusion`` named ``cli`` or ``cli_*``, or inside a ``cli`` or
``cli_*`` package (a command line split into one module per command group), has at most 700
lines.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("sim", "fusion", "scenes")
SIM_LAYERS = (
    ("sim.scene",),                                                     # the scene model
    ("sim.render", "sim.mitsuba_sensor", "sim.variant"),                # the renderer
    ("sim.shader", "sim.two_camera", "sim.flow", "sim.scene_check"),    # what renders through it
    ("sim.simulate",),                                                  # the simulation
    ("sim.dataset",),                                                   # datasets
    ("sim.cli",),                                                       # the command line
)
"""sim's layers from the bottom, as dotted prefixes: a module of one imports none of a later one."""
FORBIDDEN: dict[str, tuple[str, ...]] = {
    "sim": ("fusion",),
    "scenes": ("fusion",),
    **{lower: tuple(upper for above in SIM_LAYERS[i + 1:] for upper in above)
       for i, layer in enumerate(SIM_LAYERS) for lower in layer},
}
"""Lower module prefix -> the prefixes above it that it may not import (see the module's text)."""
CLI_PACKAGES = ("sim", "fusion")
MAX_CLI_LINES = 700
"""Most lines of one command-line module."""


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


def _import_nodes(tree: ast.AST):
    """Every Import / ImportFrom node of ``tree``, at any depth: in functions and under
    ``if TYPE_CHECKING:`` alike."""
    return (node for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom))


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


def _within(module: str, prefix: str) -> bool:
    """Whether ``module`` is ``prefix`` or inside it (``sim.scene.x`` is in ``sim.scene``,
    ``sim.scenery`` is not)."""
    return module == prefix or module.startswith(prefix + ".")


def _upward(graph: dict[str, dict[str, int]],
            forbidden: dict[str, tuple[str, ...]] = FORBIDDEN) -> list[str]:
    """Every import that ``forbidden`` forbids, ``a imports b (line N)``, once each."""
    return [f"{a} imports {b} (line {line})"
            for a, targets in sorted(graph.items())
            for b, line in sorted(targets.items())
            if any(_within(a, lower) and any(_within(b, upper) for upper in uppers)
                   for lower, uppers in forbidden.items())]


def _is_cli(path: str) -> bool:
    """Whether the module at ``path`` (``fusion/cli.py``, relative to the root) belongs to a
    command line: in :data:`CLI_PACKAGES`, and named ``cli`` or ``cli_*`` or inside a ``cli``
    or ``cli_*`` package."""
    parts = Path(path).with_suffix("").parts
    return (parts[0] in CLI_PACKAGES
            and any(part == "cli" or part.startswith("cli_") for part in parts[1:]))


def _thick_cli(lengths: dict[str, int], limit: int = MAX_CLI_LINES) -> list[str]:
    """The command-line modules of ``lengths`` (path -> lines) longer than ``limit`` lines."""
    return [f"{path}: {lines} lines (at most {limit})"
            for path, lines in sorted(lengths.items()) if _is_cli(path) and lines > limit]


def module_lengths() -> dict[str, int]:
    """Path relative to the root (``fusion/cli.py``) -> lines, for every module of the packages."""
    return {path.relative_to(ROOT).as_posix():
            len(path.read_text(encoding="utf-8").splitlines())
            for path in _modules().values()}


def test_graph_sees_the_project():
    """The reader finds the modules and edges it must (so that an empty graph cannot pass)."""
    graph = import_graph()
    assert {"sim.noise", "sim.radiometry", "sim.validation", "fusion.methods", "fusion.fill.dense",
            "fusion.methods.baselines", "scenes"} <= set(graph)
    assert "sim.camera" in graph["fusion.fill.dense"]            # a top-level import
    assert "fusion.fill.filling" in graph["fusion.methods.surface_fit"]
    # a function-level import
    assert "sim.capture_errors" in graph["fusion.scoring"]
    # a type-only import (under if TYPE_CHECKING:)
    assert "sim.scene" in graph["sim.simulate._inputs"]
    # the command lines are among the modules measured
    assert {"sim/cli.py", "fusion/cli.py"} <= {path for path in module_lengths() if _is_cli(path)}


def test_type_only_imports_are_edges():
    """An import under ``if TYPE_CHECKING:`` (either spelling) is read like any other."""
    source = ("from typing import TYPE_CHECKING\n"
              "import typing\n"
              "if TYPE_CHECKING:\n"
              "    from fusion.fill.dense import DenseParams\n"
              "if typing.TYPE_CHECKING:\n"
              "    import fusion.io\n"
              "else:\n"
              "    import fusion.scoring\n")
    found = {alias.name if isinstance(node, ast.Import) else f"{node.module}.{alias.name}"
             for node in _import_nodes(ast.parse(source)) for alias in node.names}
    assert {"fusion.fill.dense.DenseParams", "fusion.io", "fusion.scoring"} <= found


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


def test_layering_inside_sim_on_a_known_graph():
    """The layer table catches the scene model importing the renderer (or anything above it,
    at any depth of either package), and lets the layers import downwards."""
    graph = {"sim.scene.procedural": {"sim.render": 41, "sim.scene._model": 43},
             "sim.scene": {"sim.simulate._run": 9, "sim.camera": 2},
             "sim.scene._toml": {"sim.textures": 5},
             "sim.scenery": {"sim.render": 1},                      # not the scene model
             "sim.render": {"sim.scene._model": 3, "sim.variant": 4},
             "sim.simulate._run": {"sim.render": 6, "sim.scene": 7, "sim.dataset._jobs": 8},
             "sim.scene_check": {"sim.render": 1, "sim.scene": 2}}
    assert _upward(graph) == ["sim.scene imports sim.simulate._run (line 9)",
                              "sim.scene.procedural imports sim.render (line 41)",
                              "sim.simulate._run imports sim.dataset._jobs (line 8)"]
    assert _upward(graph, {}) == []


def test_cli_size_on_known_modules():
    """The size check measures command-line modules only, as one file or a package."""
    lengths = {"fusion/cli.py": 701, "sim/cli.py": 700, "fusion/cli/fill.py": 900,
               "fusion/cli/__init__.py": 20, "sim/cli_dataset.py": 750, "fusion/client.py": 5000,
               "fusion/clip.py": 5000, "fusion/methods/paper.py": 900, "scenes/cli.py": 900}
    assert _thick_cli(lengths) == ["fusion/cli.py: 701 lines (at most 700)",
                                   "fusion/cli/fill.py: 900 lines (at most 700)",
                                   "sim/cli_dataset.py: 750 lines (at most 700)"]
    assert _thick_cli(lengths, limit=5000) == []


def test_no_import_loop():
    """No module of sim, fusion or scenes imports itself through others (top-level and
    function-level imports alike)."""
    graph = import_graph()
    loops = _loops(graph)
    assert not loops, ("import loops (module:line of each import):\n"
                       + "\n".join(_describe(graph, loop) for loop in loops))


def test_no_upward_import():
    """Neither sim nor scenes imports fusion (data-making below data-consuming), and no layer of
    sim imports one above it (:data:`FORBIDDEN`), at any level."""
    graph = import_graph()
    offending = _upward(graph)
    assert not offending, "upward imports:\n" + "\n".join(offending)


def test_every_layer_of_the_table_exists():
    """Each prefix of :data:`FORBIDDEN` names modules of today's tree (a renamed layer would
    otherwise make its row pass vacuously)."""
    modules = set(import_graph())
    for lower, uppers in FORBIDDEN.items():
        for prefix in (lower, *uppers):
            assert any(_within(name, prefix) for name in modules), f"no module {prefix}"


def test_command_lines_are_thin():
    """Every command-line module of sim and fusion has at most MAX_CLI_LINES lines."""
    thick = _thick_cli(module_lengths())
    assert not thick, "command-line modules too long:\n" + "\n".join(thick)
