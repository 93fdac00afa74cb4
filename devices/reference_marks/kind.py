"""The reference marks monitor as a device of every station: its [reference] section, how it opens and how it is
emulated."""

from __future__ import annotations

from devices.config import SerialSection
from devices.reference_marks.driver import ReferenceMarks
from devices.registry import serial_kind


def _emulator() -> type:
    from devices.reference_marks.emulator import ReferenceEmulator

    return ReferenceEmulator


DEVICE_KIND = serial_kind("reference", SerialSection, ReferenceMarks, _emulator, core=True)
