"""The shaker as a device a station may have: how it opens and how it is emulated (its [shaker] section, the
table's envelope, is drivers.shaker.envelope.ShakerSection)."""

from __future__ import annotations

from typing import Any

from drivers.errors import DriverError
from drivers.registry import DeviceKind
from drivers.shaker.driver import ShakerController
from drivers.shaker.envelope import ShakerSection
from drivers.shaker.protocol import DEVICE
from station.clock import Clock


def open_shaker(section: ShakerSection, clock: Clock) -> ShakerController:
    if section.port is None:
        raise DriverError(DEVICE, "no serial port configured for [shaker]")
    shaker = ShakerController(section.port, section, baud=section.baud, clock=clock).open()
    try:
        shaker.identify()
    except DriverError:
        shaker.close()
        raise
    return shaker


def emulate_shaker(section: ShakerSection, world: Any) -> Any:
    from drivers.shaker.emulator import ShakerEmulator

    emulator = ShakerEmulator(world, section)
    return world.attach(emulator)


DEVICE_KIND = DeviceKind("shaker", ShakerSection, open_shaker, emulate_shaker)
