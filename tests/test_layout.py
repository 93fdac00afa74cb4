"""The layout is the data flow: each layer imports only the layers it stands on, no cycles, no emulator in a driver.

The layers (issue 29): station's core (station/ outside the packages below) < station.twin < station.engine <
drivers < procedures, each importing itself and the layers below; station.gap imports only the core and the twin
(it diagnoses stored sessions against the twin and knows no station that ran them); web imports anything but the
CLI; station.cli stands on top. The seams, each by design:
- station.engine.registry imports the `procedures` package, and only it, to scan the procedure library by name:
  the engine drives a station through station.engine.protocols and knows no procedure module;
- station.notebook, in the core, is the facade that notebooks reach as `station.open_store` (lazily, so
  `import station` stays light): it sits on top of what it shows (stores, results, gap reports), so it may import
  any layer but web and the CLI;
- emulators are the only driver modules that import the twin, besides the assembly (drivers.station and
  drivers.world build the simulated station around the twin's world);
- no module of any layer imports an emulator but another emulator (the simulated world chains them), a device's
  kind (which starts its emulator) and the assembly: drivers open the real protocol, and web imports no driver at
  all (its stations come from config/panel.toml, and it reaches them through their control channels).
Imports under `if TYPE_CHECKING:` and inside functions count: a cycle of type hints is a cycle of knowledge.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("station", "drivers", "procedures", "web")
STACK = ("core", "twin", "engine", "drivers", "procedures")
MAY_IMPORT = {layer: set(STACK[: i + 1]) for i, layer in enumerate(STACK)} | {
    "gap": {"core", "twin", "gap"},
    "web": {*STACK, "gap", "web"},
    "cli": {*STACK, "gap", "web", "cli"},
}
INSIDE_STATION = ("twin", "engine", "gap", "cli")
ASSEMBLY = ("drivers.station", "drivers.world")


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
    return _imports_in(path.read_text(encoding="utf-8"), module, is_package=path.name == "__init__.py")


def _imports_in(source: str, module: str, *, is_package: bool) -> set[str]:
    """The known modules that `module`'s source imports anywhere: at the top, in functions, under TYPE_CHECKING."""
    package = module if is_package else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
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
    """Whether `module` importing `target` breaks the layers or one of their seams (the module docstring)."""
    layer, to = _layer(module), _layer(target)
    if to not in MAY_IMPORT[layer]:
        registry_scan = module == "station.engine.registry" and target == "procedures"
        notebook_facade = module == "station.notebook" and to not in ("web", "cli")
        return not (registry_scan or notebook_facade)
    if layer == "drivers" and to == "twin" and not (_is_emulator(module) or module in ASSEMBLY):
        return True  # a driver knows its protocol, not the twin
    return _is_emulator(target) and not (_is_emulator(module) or module.endswith(".kind") or module in ASSEMBLY)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_follow_the_data_flow(module: str) -> None:
    wrong = [target for target in sorted(GRAPH[module]) if _against_layout(module, target)]
    assert wrong == [], f"{module} imports {wrong} against the layout"


@pytest.mark.parametrize(
    ("module", "target", "against"),
    [
        ("station.gap.fit", "procedures.common.uncertainty", True),
        ("station.gap.api", "drivers.registry", True),
        ("station.gap.api", "station.engine.registry", True),
        ("station.gap.fit", "station.twin.config", False),
        ("station.gap.fit", "station.least_squares", False),
        ("web.app", "station.cli.cli", True),
        ("web.history", "procedures.integral_precession.identify", False),
        ("web.app", "drivers.servo.emulator", True),
        ("station.cli.cli", "web.app", False),
        ("station.twin.crank", "station.engine.protocols", True),
        ("station.engine.session", "drivers.errors", True),
        ("station.engine.session", "procedures", True),
        ("station.engine.registry", "procedures", False),
        ("station.engine.registry", "procedures.tumble.procedure", True),
        ("procedures.tumble.analysis", "station.gap.api", True),
        ("station.store", "station.twin.config", True),
        ("station.notebook", "station.gap.api", False),
        ("station.notebook", "web.app", True),
        ("drivers.servo.driver", "station.twin.crank", True),
        ("drivers.servo.emulator", "station.twin.crank", False),
        ("drivers.world", "station.twin.config", False),
        ("drivers.servo.driver", "drivers.servo.emulator", True),
        ("drivers.servo.kind", "drivers.servo.emulator", False),
        ("procedures.tumble.procedure", "drivers.voltmeter.emulator", True),
    ],
)
def test_the_rule_refuses_what_the_layout_forbids(module: str, target: str, against: bool) -> None:
    assert _against_layout(module, target) is against


def test_type_only_and_lazy_imports_count() -> None:
    source = (
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from procedures.common.uncertainty import Budget\n"
        "def later() -> None:\n    from ..engine import registry\n"
    )
    found = _imports_in(source, "station.gap.fit", is_package=False)
    assert {"procedures.common.uncertainty", "station.engine.registry"} <= found
