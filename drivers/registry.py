"""Every device a station may have, found by name: the vibration table's five, voltmeters, chambers, IMUs, ...

A device package's kind module (`drivers/<device>/kind.py`) that defines a module attribute

    DEVICE_KIND = DeviceKind(name="voltmeter", section=VoltmeterSection, open=..., emulate=...)

is a device a station may have. Its configuration section `[name]` is
optional in a station file; when present it is parsed with `section` (a
`@settings` dataclass of station.validation whose fields declare what they
allow: `spec(in_range(lo, hi))`, `optional=True` for a serial port that a
simulated station fills in), the device is opened with `open(section, clock)`
and, on a simulated station, its emulator is started first with
`emulate(section, world)` (an object with `.port` for a serial device, and
`close()`); `open` then receives the section with the emulator's port.
Procedures reach it as `ctx.hw.device(name)` and check its limits in planning
through `ctx.model.section(name)`. What the station does with an opened device
follows from the engine's protocols it implements (station.engine.protocols: a
`Stoppable` device is stopped by the station's safe and emergency stops).

The five devices of the vibration table (servo, grating, reference, counter,
indexing_head) are found the same way, with `core=True`: they are fields of
drivers.config.StationConfig (the head's section required; the table's four,
drivers.config.TABLE_SECTIONS, all present or all left out by a station without a
crank table), and drivers.station opens them with the wiring only a station knows
as keyword arguments of `open` (the servo's limits, the head's motion interlock).
"""

from __future__ import annotations

import importlib
import importlib.util
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any

from station.clock import Clock


@dataclass(frozen=True)
class DeviceKind:
    name: str  # the config section and the device's name
    section: type  # the section's @settings dataclass (station.validation)
    open: Callable[..., Any]  # (section, clock, **wiring of a core device) -> opened driver with close()
    emulate: Callable[[Any, Any], Any]  # (section, SimStation) -> started emulator with .port and close()
    core: bool = False  # the vibration table's four and the head: a StationConfig field (drivers.config)


def serial_kind(
    name: str, section: type, driver: type, emulator: Callable[[], type], *, core: bool = False
) -> DeviceKind:
    """The kind of a serial device with nothing to configure but its port and baud rate: opened as
    `driver(port, baud=, clock=).open()`, emulated as `emulator()(world, baud=)`, started; `emulator` returns the
    emulator class when called (an import inside a function, so that a real station never loads the twin)."""

    def open_device(sec: Any, clock: Clock) -> Any:
        return driver(sec.port or "", baud=sec.baud, clock=clock).open()

    def emulate_device(sec: Any, world: Any) -> Any:
        emu = emulator()(world, baud=sec.baud)
        return world.attach(emu)

    return DeviceKind(name, section, open_device, emulate_device, core=core)


@cache
def device_kinds() -> dict[str, DeviceKind]:
    """Every DEVICE_KIND declared by a device package's kind module (drivers/<device>/kind.py), by name."""
    import drivers

    kinds: dict[str, DeviceKind] = {}
    for mod in pkgutil.iter_modules(drivers.__path__):
        if not mod.ispkg or importlib.util.find_spec(f"drivers.{mod.name}.kind") is None:
            continue
        kind = getattr(importlib.import_module(f"drivers.{mod.name}.kind"), "DEVICE_KIND", None)
        if isinstance(kind, DeviceKind):
            kinds[kind.name] = kind
    return kinds
