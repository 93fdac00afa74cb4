"""The temperature chamber as a device a station may have: its [temperature_chamber] section
(with the station's limits for the instrument inside), how it opens and how it is emulated."""

from __future__ import annotations

from typing import Any

from drivers.config import SerialSection
from drivers.registry import DeviceKind
from drivers.temperature_chamber.driver import TemperatureChamber
from station.clock import Clock
from station.validation import in_range, settings, spec


@settings
class TemperatureChamberSection(SerialSection):
    """[temperature_chamber]: the controller's address and the station's limits for the instrument inside."""

    address: int = spec(in_range(0, 99))
    setpoint_min_c: float = spec(in_range(-100.0, 200.0))
    setpoint_max_c: float = spec(in_range(-100.0, 200.0))
    ramp_max_c_per_min: float = spec(in_range(0.0, 20.0, lo_open=True))
    stable_band_c: float = spec(in_range(0.0, 5.0, lo_open=True))  # "at temperature": |PV - SL| within this
    time_constant_s: float = spec(in_range(1.0, 36_000.0))  # product temperature lag, for soak estimates
    timeout_s: float = spec(in_range(0.0, 10.0, lo_open=True))

    def __post_init__(self) -> None:
        if not self.setpoint_min_c < self.setpoint_max_c:
            raise ValueError(
                f"[temperature_chamber] setpoint_min_c = {self.setpoint_min_c!r}: "
                f"not allowed (allowed: < setpoint_max_c = {self.setpoint_max_c!r})"
            )


def _open(section: TemperatureChamberSection, clock: Clock) -> TemperatureChamber:
    return TemperatureChamber(
        section.port or "", baud=section.baud, address=section.address, setpoint_min_c=section.setpoint_min_c,
        setpoint_max_c=section.setpoint_max_c, ramp_max_c_per_min=section.ramp_max_c_per_min,
        stable_band_c=section.stable_band_c, time_constant_s=section.time_constant_s, timeout_s=section.timeout_s,
        clock=clock,
    ).open()  # fmt: skip


def _emulate(section: TemperatureChamberSection, world: Any) -> Any:
    from drivers.temperature_chamber.emulator import ChamberEmulator

    emu = ChamberEmulator(world, baud=section.baud, address=section.address, time_constant_s=section.time_constant_s)
    return world.attach(emu)


DEVICE_KIND = DeviceKind("temperature_chamber", TemperatureChamberSection, _open, _emulate)
