"""The counter/timer board as a device of every station: its [counter] section, how it opens and how it is emulated."""

from __future__ import annotations

from typing import Any

from devices.config import SerialSection
from devices.counter_timer.driver import CounterTimer
from devices.registry import DeviceKind
from station.clock import Clock


def open_counter(section: SerialSection, clock: Clock) -> CounterTimer:
    return CounterTimer(section.port or "", baud=section.baud, clock=clock).open()


def emulate_counter(section: SerialSection, world: Any) -> Any:
    from devices.counter_timer.emulator import CounterEmulator

    emulator = CounterEmulator(world, baud=section.baud)
    emulator.start()
    return emulator


DEVICE_KIND = DeviceKind("counter", SerialSection, open_counter, emulate_counter, core=True)
