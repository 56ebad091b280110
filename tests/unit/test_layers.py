"""The layout's rules, checked on the source: imports run one way through the layers, no module imports
itself back round a circle, and the pure core imports nothing that does I/O (docs/design.md, "Layers")."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "c20sim"
#: The layers from the wire inwards-out: a module may import its own layer and those before it.
LAYERS = ("wire", "drive", "core", "audit", "drill", "transport", "control", "traffic", "scenario")
#: What the pure core (wire, drive, core) may not import: event loops, sockets, ports, threads, screens, masters.
IO_MODULES = ("asyncio", "socket", "selectors", "serial", "threading", "subprocess", "aiohttp", "textual", "pymodbus")


def _name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _imports(path: Path) -> set[str]:
    """Every module (of c20sim or not) that ``path`` imports, at the top or inside a function."""
    name = _name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                full = f"{target}.{alias.name}"
                found.add(full if _is_module(full) else target)
    return found


GRAPH = {_name(p): _imports(p) for p in PACKAGE.rglob("*.py")}


def _layer(name: str) -> int:
    """The layer's rank; the package itself and the front ends (cli, serve, testing, tui, ...) come last."""
    parts = name.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else len(LAYERS)


def test_the_graph_is_read() -> None:
    assert "c20sim.core.simulator" in GRAPH["c20sim.core.bus"] or "c20sim.core.slave" in GRAPH["c20sim.core.bus"]
    assert "c20sim.wire.protocol" in GRAPH["c20sim.core.bus"]
    assert {"c20sim.control.routes", "aiohttp"} <= GRAPH["c20sim.control.http"]


def test_imports_run_one_way_through_the_layers() -> None:
    upward = sorted(
        (name, target)
        for name, targets in GRAPH.items()
        for target in targets
        if target.startswith("c20sim") and _layer(target) > _layer(name)
    )
    assert upward == []


def test_no_import_circle() -> None:
    state: dict[str, int] = {}
    circles: list[list[str]] = []

    def visit(name: str, path: list[str]) -> None:
        state[name] = 1
        path.append(name)
        for target in sorted(GRAPH[name]):
            if target not in GRAPH:
                continue
            if state.get(target) == 1:
                circles.append([*path[path.index(target) :], target])
            elif target not in state:
                visit(target, path)
        path.pop()
        state[name] = 2

    for name in sorted(GRAPH):
        if name not in state:
            visit(name, [])
    assert circles == []


@pytest.mark.parametrize("layer", ["wire", "drive", "core", "audit", "drill"])
def test_the_pure_core_imports_no_io(layer: str) -> None:
    found = sorted(
        (name, target)
        for name, targets in GRAPH.items()
        if name == f"c20sim.{layer}" or name.startswith(f"c20sim.{layer}.")
        for target in targets
        if target.split(".")[0] in IO_MODULES
    )
    assert found == []


def test_the_layers_are_the_folders() -> None:
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert set(LAYERS) <= folders
    assert folders - set(LAYERS) == {"tui", "browser"}  # the front ends with a folder of their own
