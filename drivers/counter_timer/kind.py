"""The counter/timer board as a device of every station: its [counter] section, how it opens and how it is emulated."""

from __future__ import annotations

from drivers.config import SerialSection
from drivers.counter_timer.driver import CounterTimer
from drivers.registry import serial_kind


def _emulator() -> type:
    from drivers.counter_timer.emulator import CounterEmulator

    return CounterEmulator


DEVICE_KIND = serial_kind("counter", SerialSection, CounterTimer, _emulator, core=True)
