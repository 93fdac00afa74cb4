"""The layout is the data flow: layers import only downward, no cycles, drivers never import emulators.

Layers, from the bottom: the core (station/ outside the packages below) < station.twin < station.engine < drivers <
procedures < station.gap < web < station.cli.
A module may import its own layer and the layers below, with these exceptions, each a seam by design:
- the engine imports no driver and no procedure: it drives a station through station.engine.protocols, and the
  procedure library is found by name (station.engine.registry imports the `procedures` package to scan it);
- the core knows no driver, procedure, twin or engine; its one exception is `station.notebook`, the
  facade that notebooks reach as `station.open_store` (lazily, so `import station` stays light), which sits
  on top of everything it shows (stores, results, gap reports);
- emulators are the only driver modules that import the twin, and no driver imports an emulator.
Imports under `if TYPE_CHECKING:` count: a cycle of type hints is a cycle of knowledge.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("station", "drivers", "procedures", "web")
LAYERS = ("core", "twin", "engine", "drivers", "procedures", "gap", "web", "cli")
RANK = {name: i for i, name in enumerate(LAYERS)}
INSIDE_STATION = ("twin", "engine", "gap", "cli")


def _layer(module: str) -> str:
    parts = module.split(".")
    if parts[0] != "station":
        return parts[0]
    return parts[1] if len(parts) > 1 and parts[1] in INSIDE_STATION else "core"


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
            mods[".".join(parts)] = path
    return mods


MODULES = _modules()


def _resolve(name: str) -> str | None:
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(module: str) -> set[str]:
    path = MODULES[module]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            targets = [base, *(f"{base}.{a.name}" for a in node.names)]
        else:
            continue
        for target in targets:
            resolved = _resolve(target)
            if resolved and resolved != module:
                found.add(resolved)
    return found


GRAPH = {m: _imports(m) for m in MODULES}


def _is_emulator(module: str) -> bool:
    return module.rsplit(".", 1)[-1] == "emulator"


def test_the_layout_has_its_packages() -> None:
    assert all((ROOT / pkg / "__init__.py").is_file() for pkg in PACKAGES)
    assert all((ROOT / "station" / pkg / "__init__.py").is_file() for pkg in INSIDE_STATION)
    devices = [p for p in (ROOT / "drivers").iterdir() if (p / "__init__.py").is_file()]
    assert len(devices) >= 12
    for device in devices:
        assert {"driver.py", "emulator.py", "protocol.py", "kind.py"} <= {f.name for f in device.iterdir()}, device


def test_no_import_cycle() -> None:
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in GRAPH:
        if v not in index:
            visit(v)
    assert cycles == []


def _against_layout(module: str, target: str) -> bool:
    layer, to = _layer(module), _layer(target)
    if RANK[to] > RANK[layer]:
        return not (module == "station.engine.registry" and target == "procedures") and module != "station.notebook"
    if layer == "engine":
        return to == "drivers"
    if layer != "drivers":
        return False
    assembly = module in ("drivers.station", "drivers.world")
    if to == "twin" and not (_is_emulator(module) or assembly):
        return True  # a driver knows its protocol, not the twin
    return _is_emulator(target) and not (_is_emulator(module) or module.endswith(".kind") or assembly)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_follow_the_data_flow(module: str) -> None:
    wrong = [target for target in sorted(GRAPH[module]) if _against_layout(module, target)]
    assert wrong == [], f"{module} imports {wrong} against the layout"
