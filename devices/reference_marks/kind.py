"""The reference marks monitor as a device of every station: its [reference] section, how it opens and how it is
emulated."""

from __future__ import annotations

from typing import Any

from devices.config import SerialSection
from devices.reference_marks.driver import ReferenceMarks
from devices.registry import DeviceKind
from station.clock import Clock


def open_reference(section: SerialSection, clock: Clock) -> ReferenceMarks:
    return ReferenceMarks(section.port or "", baud=section.baud, clock=clock).open()


def emulate_reference(section: SerialSection, world: Any) -> Any:
    from devices.reference_marks.emulator import ReferenceEmulator

    emulator = ReferenceEmulator(world, baud=section.baud)
    emulator.start()
    return emulator


DEVICE_KIND = DeviceKind("reference", SerialSection, open_reference, emulate_reference, core=True)
