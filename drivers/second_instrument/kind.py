"""A second PIGA on the indexing head with a counter/timer channel of its own (seed 003's dual-instrument method):
the station's [second_instrument] section, how its counter opens and how it is emulated.

The orthogonal 4-pose method (seed 003 section 4) counts two PIGAs on one fixture: the
second one's output pulses go to a second counter/timer board, the same board and
protocol as the station's (drivers.counter_timer.driver.CounterTimer) on its own port. Station
file section:

    [second_instrument]
    port = "/dev/ttyUSB4"   # left out on a simulated station
    baud = 921600

On a simulated station the emulator is the station's counter/timer emulator fed by the
second PIGA on the simulated fixture (drivers.second_instrument.emulator).
"""

from __future__ import annotations

from typing import Any

from drivers.config import SerialSection
from drivers.registry import DeviceKind
from drivers.second_instrument.driver import CounterTimer
from station.clock import Clock


def open_counter(section: SerialSection, clock: Clock) -> CounterTimer:
    return CounterTimer(section.port or "", baud=section.baud, clock=clock).open()


def emulate(section: SerialSection, world: Any) -> Any:
    from drivers.second_instrument.emulator import start_counter_emulator

    return start_counter_emulator(world, section.baud)


DEVICE_KIND = DeviceKind("second_instrument", SerialSection, open_counter, emulate)
