"""The voltmeter as a device a station may have: its [voltmeter] section, how it opens and how it is emulated."""

from __future__ import annotations

from typing import Any

from drivers.config import SerialSection
from drivers.registry import DeviceKind
from drivers.voltmeter.driver import Voltmeter
from station.clock import Clock
from station.validation import in_range, settings, spec


@settings
class VoltmeterSection(SerialSection):
    """[voltmeter]: the port and the mains frequency that sets the aperture of one power-line cycle."""

    line_hz: float = spec((lambda v: v in (50.0, 60.0), "50 or 60 (the mains frequency, Hz)"))
    timeout_s: float = spec(in_range(0.0, 10.0, lo_open=True))


def _open(section: VoltmeterSection, clock: Clock) -> Voltmeter:
    return Voltmeter(section.port or "", baud=section.baud, line_hz=section.line_hz, timeout_s=section.timeout_s,
                     clock=clock).open()  # fmt: skip


def _emulate(section: VoltmeterSection, world: Any) -> Any:
    from drivers.voltmeter.emulator import VoltmeterEmulator

    emu = VoltmeterEmulator(world, baud=section.baud, line_hz=section.line_hz)
    return world.attach(emu)


DEVICE_KIND = DeviceKind("voltmeter", VoltmeterSection, _open, _emulate)
