"""The second instrument's counter channel: the station's counter/timer board on a port of its own, so its driver
is drivers.counter_timer.driver.CounterTimer (seed 003 section 4, two PIGAs counted at once)."""

from __future__ import annotations

from drivers.counter_timer.driver import CounterTimer

__all__ = ["CounterTimer"]
