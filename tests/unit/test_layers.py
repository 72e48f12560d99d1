"""The rooms of the package in layers, declared once here as data, and kept by reading every
module's imports (function-local and `TYPE_CHECKING` ones included: each is a dependency a
reader has to follow).

A module may import from its own layer and the layers below it, never from one above; and no
import, wherever it stands in the module, may close a loop, of modules or of rooms (a room: a
top-level module or package of `gateway`, as the architecture page's table has them).
`docs/pages/architecture.md` describes the rooms; this is where their order is written down.
"""

from __future__ import annotations

import ast
import functools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "gateway"

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "foundations",
        (
            "gateway",  # the package's own __init__: its version, how its engine room runs
            "gateway.compiled",  # which modules mypyc compiles, and whether they are today's
            "gateway.build_backend",  # the package's build (pyproject.toml): never run by it
            "gateway.errors",
            "gateway.logs",
            "gateway.exit_codes",
            "gateway.version",
            "gateway.libc",
            "gateway.timerfd",
            "gateway.timer_slack",
            "gateway.backoff",
            "gateway.buckets",
            "gateway.nearest",
            "gateway.passwords",
            "gateway.progress",
            "gateway.listen",
            "gateway.http_endpoint",
            "gateway.exposition",
            "gateway.metric_families",
            "gateway.event_loop",
            "gateway.systemd",
            "gateway.control",
            "gateway.collector",
            "gateway.tasks",
            "gateway.large_allocations",  # glibc's mmap threshold, pinned at start (`run`)
            "gateway.memory_trace",  # tracemalloc snapshots on a signal, when asked (`run`)
        ),
    ),
    ("framing and makers' knowledge", ("gateway.modbus", "gateway.profile")),
    (
        "the line, the front door, the configuration",
        ("gateway.bus", "gateway.tcp", "gateway.config"),
    ),
    ("routing and the field tools' masters", ("gateway.routing", "gateway.tools")),
    ("settings", ("gateway.settings",)),
    (
        "state: the store, the poller, health",
        (
            "gateway.store",
            "gateway.poller",
            "gateway.health",
            "gateway.event_log",
            "gateway.setpoint_limit",
            "gateway.redundancy",  # the role on the lines: the bus's ports, the store's events
        ),
    ),
    ("front doors for people", ("gateway.console", "gateway.mqtt")),
    (
        "beside them: Sparkplug and OPC UA on MQTT's parts, /metrics over every part",
        ("gateway.sparkplug", "gateway.opcua", "gateway.metrics"),
    ),
    ("wiring", ("gateway.app",)),
    ("commands", ("gateway.commands", "gateway.cli", "gateway.__main__")),
    ("instruments (never imported by the service)", ("gateway.instruments",)),
)
"""Lowest first: each layer's rooms (a package stands for every module in it)."""


@dataclass(frozen=True)
class Import:
    importer: str
    imported: str
    line: int
    via: Import | None = None
    """Between rooms: the first import of a module of one by a module of the other."""

    def __str__(self) -> str:
        if self.via is not None:
            return f"{self.importer} -> {self.imported} ({self.via})"
        path = module_paths()[self.importer].relative_to(PACKAGE.parent)
        return f"{path}:{self.line}: {self.importer} imports {self.imported}"


@functools.cache
def module_paths() -> dict[str, Path]:
    """Every module of the package by dotted name (a package by its name: its __init__)."""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


def layer_of(module: str) -> int:
    """The index in LAYERS of the room `module` is in (its longest matching prefix)."""
    best, index = "", -1
    for number, (_, rooms) in enumerate(LAYERS):
        for room in rooms:
            inside = module == room or (room != "gateway" and module.startswith(room + "."))
            if inside and len(room) > len(best):
                best, index = room, number
    return index


def _target(name: str, modules: dict[str, Path]) -> str | None:
    """The package's module `name` names (a name inside a module: that module)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def imports_of(module: str, modules: dict[str, Path]) -> Iterator[Import]:
    """Every import of the package's own modules in `module`, wherever it stands."""
    path = modules[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*parts, base] if base else parts)
            # `from package import submodule` imports the submodule; a name, its module.
            names = [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            if name == "gateway" or name.startswith("gateway."):
                target = _target(name, modules)
                if target is not None and target != module:
                    yield Import(module, target, node.lineno)


@functools.cache
def import_graph() -> dict[str, list[Import]]:
    """Each module's imports of the package's modules, one for each module and line."""
    modules = module_paths()
    return {module: list(dict.fromkeys(imports_of(module, modules))) for module in modules}


def room_of(module: str) -> str:
    """ "gateway.bus" for "gateway.bus.line"; "gateway.app" for itself."""
    return ".".join(module.split(".")[:2])


def room_graph(graph: dict[str, list[Import]]) -> dict[str, list[Import]]:
    """The imports between rooms, each with the first module import that makes it."""
    rooms: dict[str, dict[str, Import]] = {room_of(module): {} for module in graph}
    for edges in graph.values():
        for edge in edges:
            importer, imported = room_of(edge.importer), room_of(edge.imported)
            if importer != imported:
                rooms[importer].setdefault(imported, Import(importer, imported, 0, edge))
    return {room: list(edges.values()) for room, edges in rooms.items()}


def loops(graph: dict[str, list[Import]]) -> list[list[Import]]:
    """One closed path of imports for every group of modules that import each other."""
    order: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[Import]] = []

    def visit(module: str) -> None:  # Tarjan's strongly connected components
        order[module] = low[module] = len(order)
        stack.append(module)
        for edge in graph[module]:
            if edge.imported not in order:
                visit(edge.imported)
                low[module] = min(low[module], low[edge.imported])
            elif edge.imported in stack:
                low[module] = min(low[module], order[edge.imported])
        if low[module] == order[module]:
            group = stack[stack.index(module) :]
            del stack[stack.index(module) :]
            if len(group) > 1:
                found.append(_cycle_within(set(group), graph))

    for module in graph:
        if module not in order:
            visit(module)
    return found


def _cycle_within(group: set[str], graph: dict[str, list[Import]]) -> list[Import]:
    """The shortest closed path through the group from its first module back to it."""
    start = min(group)
    came_by: dict[str, Import] = {}
    frontier = [start]
    while frontier:
        following = []
        for module in frontier:
            for edge in graph[module]:
                if edge.imported == start:
                    path = [edge]
                    while path[0].importer != start:
                        path.insert(0, came_by[path[0].importer])
                    return path
                if edge.imported in group and edge.imported not in came_by:
                    came_by[edge.imported] = edge
                    following.append(edge.imported)
        frontier = following
    raise AssertionError(f"no loop through {start}")  # a strongly connected group has one


def test_every_module_is_in_a_layer() -> None:
    outside = [module for module in module_paths() if layer_of(module) < 0]
    assert outside == [], "add these to a layer in LAYERS"


def test_no_import_reaches_up_a_layer() -> None:
    upward = [
        str(edge)
        for edges in import_graph().values()
        for edge in edges
        if layer_of(edge.imported) > layer_of(edge.importer)
    ]
    assert upward == [], "\n".join(upward)


def test_no_import_loop() -> None:
    found = ["\n  ".join(str(edge) for edge in cycle) for cycle in loops(import_graph())]
    assert found == [], "\n".join(found)


def test_no_loop_between_rooms() -> None:
    found = [
        "\n  ".join(str(edge) for edge in cycle) for cycle in loops(room_graph(import_graph()))
    ]
    assert found == [], "\n".join(found)


def test_the_checks_catch_what_they_are_for() -> None:
    """The graph has the imports a reader sees: a function-local one (the application's MQTT
    bridge) and one under TYPE_CHECKING (the protocol's fault table)."""
    graph = import_graph()
    app = {edge.imported for edge in graph["gateway.app"]}
    assert "gateway.mqtt" in app  # imported inside a method
    protocol = {edge.imported for edge in graph["gateway.profile.protocol"]}
    assert "gateway.profile.faults" in protocol  # imported under TYPE_CHECKING
    two = {"a": [Import("a", "b", 1)], "b": [Import("b", "a", 2)]}
    assert [[str(e.importer) for e in cycle] for cycle in loops(two)] == [["a", "b"]]
    assert layer_of("gateway.app") > layer_of("gateway.bus.line") > layer_of("gateway.errors")
