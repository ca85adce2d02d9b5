"""The package's import graph follows the data flow (issue 21).

Every ``import`` of every module is read with :mod:`ast`, including imports inside functions, so a
lazy import cannot hide an arrow the wrong way. The rules:

* car-side stages (sense → perceive → track → fuse → decide → plan → control) and the core modules
  import nothing from the simulator, the metrics, the pipelines, the apps, training, plots or the
  command line: a car runs them without any of those; a stage imports only earlier stages;
* no cycle between sub-packages;
* ``pipeline`` may use ``eval``'s metrics, never the other way round; only the command line imports
  ``apps``; nothing imports the command line;
* torch is imported in ``train/`` only (the runtime installs without it).
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import makeway

ROOT = Path(makeway.__file__).resolve().parent
CAR_SIDE = {"sense", "perceive", "track", "fuse", "decide", "plan", "control", "v2x"}
OFF_CAR = {"sim", "eval", "pipeline", "apps", "train", "viz", "cli", "roadside"}
ENTRY_POINTS = {"makeway.__main__"}


def _unit(module: str) -> str:
    """``makeway.perceive.audio.stream`` → ``perceive``; a top-level module is its own unit."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def _graph() -> dict[str, set[str]]:
    """Module name → every makeway module (or top-level package) it imports."""
    edges: dict[str, set[str]] = defaultdict(set)
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        name = ".".join(p for p in rel.parts if p != "__init__")
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                edges[name].add(node.module)
            elif isinstance(node, ast.Import):
                edges[name].update(a.name for a in node.names)
    return edges


GRAPH = _graph()


def _unit_edges() -> dict[str, set[str]]:
    out: dict[str, set[str]] = defaultdict(set)
    for module, targets in GRAPH.items():
        for t in targets:
            if t.startswith("makeway.") and _unit(t) != _unit(module):
                out[_unit(module)].add(_unit(t))
    return out


def test_the_graph_was_read() -> None:
    """The reader found the package (a broken walk would make every rule below pass vacuously)."""
    units = _unit_edges()
    assert {"perceive", "pipeline", "sim", "cli", "control"} <= set(units)
    assert "sim" in units["pipeline"] and "perceive" in units["pipeline"]


def test_car_side_never_imports_the_simulator_or_tools() -> None:
    bad = [
        f"{module} → {t}"
        for module, targets in GRAPH.items()
        if module not in ENTRY_POINTS
        and (_unit(module) in CAR_SIDE or (module.count(".") == 1 and _unit(module) not in OFF_CAR))
        for t in targets
        if t.startswith("makeway.") and _unit(t) in OFF_CAR
    ]
    assert bad == []


def test_car_side_stages_import_only_earlier_stages() -> None:
    """sense → perceive → track → fuse → decide → plan → control: a stage may use what an earlier
    stage offers (control uses plan's paths), never a later one."""
    order = ["sense", "perceive", "track", "fuse", "decide", "plan", "control"]
    units = _unit_edges()
    bad = [
        f"{a} → {b}"
        for a in order
        for b in units.get(a, ())
        if b in order and order.index(b) > order.index(a)
    ]
    assert bad == []


def test_no_cycle_between_subpackages() -> None:
    units = _unit_edges()
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(units.get(node, ())):
            if state.get(nxt) == 1:
                cycles.append([*stack[stack.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, [*stack, nxt])
        state[node] = 2

    for unit in sorted(units):
        if unit not in state:
            visit(unit, [unit])
    assert cycles == []


def test_one_way_arrows_between_tools() -> None:
    units = _unit_edges()
    assert "pipeline" not in units["eval"]
    assert [u for u, targets in units.items() if "apps" in targets] == ["cli"]
    assert [u for u, targets in units.items() if "cli" in targets and u != "__main__"] == []


def test_torch_only_in_training() -> None:
    users = sorted(m for m, targets in GRAPH.items() if any(t.split(".")[0] == "torch" for t in targets))
    assert users and all(m.startswith("makeway.train.") for m in users)
