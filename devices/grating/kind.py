"""The grating read head as a device of every station: its [grating] section, how it opens and how it is emulated."""

from __future__ import annotations

from typing import Any

from devices.config import SerialSection
from devices.grating.driver import GratingReadHead
from devices.registry import DeviceKind
from station.clock import Clock


def open_grating(section: SerialSection, clock: Clock) -> GratingReadHead:
    return GratingReadHead(section.port or "", baud=section.baud, clock=clock).open()


def emulate_grating(section: SerialSection, world: Any) -> Any:
    from devices.grating.emulator import GratingEmulator

    emulator = GratingEmulator(world, baud=section.baud)
    emulator.start()
    return emulator


DEVICE_KIND = DeviceKind("grating", SerialSection, open_grating, emulate_grating, core=True)
