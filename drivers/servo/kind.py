"""The vibration-table servo as a device of every station: its [servo] section, how it opens and how it is emulated."""

from __future__ import annotations

from typing import Any

from drivers.config import ServoSection
from drivers.registry import DeviceKind
from drivers.servo.driver import ServoLimits, VibrationTableServo
from station.clock import Clock


def open_servo(section: ServoSection, clock: Clock, *, limits: ServoLimits) -> VibrationTableServo:
    """The drive on the section's bus, held to the station's limits ([limits], [station])."""
    servo = VibrationTableServo(section, limits, clock)
    servo.open()
    return servo


def emulate_servo(section: ServoSection, world: Any) -> Any:
    """The drive's emulator on the section's (virtual) bus, turning the world's crank; started."""
    from drivers.servo.emulator import ServoEmulator

    emulator = ServoEmulator.from_config(section, world.clock, world.crank)
    emulator.start()
    return emulator


DEVICE_KIND = DeviceKind("servo", ServoSection, open_servo, emulate_servo, core=True)
