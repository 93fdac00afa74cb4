"""The grating read head as a device of every station: its [grating] section, how it opens and how it is emulated."""

from __future__ import annotations

from devices.config import SerialSection
from devices.grating.driver import GratingReadHead
from devices.registry import serial_kind


def _emulator() -> type:
    from devices.grating.emulator import GratingEmulator

    return GratingEmulator


DEVICE_KIND = serial_kind("grating", SerialSection, GratingReadHead, _emulator, core=True)
