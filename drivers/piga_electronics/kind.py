"""The PIGA electronics as a device a station may have: its [piga_electronics] section, how it opens and how it is
emulated."""

from __future__ import annotations

from typing import Any

from drivers.config import SerialSection
from drivers.piga_electronics.driver import PigaElectronics
from drivers.registry import DeviceKind
from station.clock import Clock
from station.validation import in_range, settings, spec


@settings
class PigaElectronicsSection(SerialSection):
    offset_max_arcsec: float = spec(in_range(0.0, 60.0, lo_open=True))
    servo_settle_s: float = spec(in_range(0.0, 600.0))  # how long beta takes to follow an offset change
    lock_timeout_s: float = spec(in_range(0.0, 600.0, lo_open=True))


def _open(section: PigaElectronicsSection, clock: Clock) -> PigaElectronics:
    return PigaElectronics(
        section.port or "",
        baud=section.baud,
        offset_max_arcsec=section.offset_max_arcsec,
        lock_timeout_s=section.lock_timeout_s,
        clock=clock,
    ).open()


def _emulate(section: PigaElectronicsSection, world: Any) -> Any:
    from drivers.piga_electronics.emulator import PigaElectronicsEmulator

    emulator = PigaElectronicsEmulator(world, baud=section.baud, settle_s=section.servo_settle_s)
    return world.attach(emulator)


DEVICE_KIND = DeviceKind("piga_electronics", PigaElectronicsSection, _open, _emulate)
