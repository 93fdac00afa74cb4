"""The IMU as a device a station may have: its [imu] section, how it opens and how it is emulated."""

from __future__ import annotations

from typing import Any

from drivers.errors import DriverError
from drivers.imu.driver import StrapdownImu
from drivers.imu.protocol import DEVICE, RATES_HZ
from drivers.registry import DeviceKind
from station.clock import Clock
from station.validation import in_range, settings, spec


@settings
class ImuSection:
    """[imu] of a station file."""

    port: str | None = spec((bool, "a device path such as /dev/ttyUSB4"), optional=True)
    baud: int = spec(in_range(115_200, 12_000_000))
    rate_hz: int = spec((lambda v: v in RATES_HZ, f"one of {', '.join(map(str, RATES_HZ))}"))


def open_imu(section: ImuSection, clock: Clock) -> StrapdownImu:
    if section.port is None:
        raise DriverError(DEVICE, "no serial port configured for [imu]")
    return StrapdownImu(section.port, baud=section.baud, rate_hz=section.rate_hz, clock=clock).open()


def emulate_imu(section: ImuSection, world: Any) -> Any:
    from drivers.imu.emulator import ImuEmulator

    emulator = ImuEmulator(world, baud=section.baud)
    return world.attach(emulator)


DEVICE_KIND = DeviceKind("imu", ImuSection, open_imu, emulate_imu)
