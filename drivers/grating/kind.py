"""The grating read head as a device of every station: its [grating] section, how it opens and how it is emulated."""

from __future__ import annotations

from drivers.config import SerialSection
from drivers.grating.driver import GratingReadHead
from drivers.registry import serial_kind


def _emulator() -> type:
    from drivers.grating.emulator import GratingEmulator

    return GratingEmulator


DEVICE_KIND = serial_kind("grating", SerialSection, GratingReadHead, _emulator, core=True)
