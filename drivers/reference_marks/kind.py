"""The reference marks monitor as a device of every station: its [reference] section, how it opens and how it is
emulated."""

from __future__ import annotations

from drivers.config import SerialSection
from drivers.reference_marks.driver import ReferenceMarks
from drivers.registry import serial_kind


def _emulator() -> type:
    from drivers.reference_marks.emulator import ReferenceEmulator

    return ReferenceEmulator


DEVICE_KIND = serial_kind("reference", SerialSection, ReferenceMarks, _emulator, core=True)
