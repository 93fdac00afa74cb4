"""Who owns time: one clock object per station, wall or virtual.

Emulators and drivers take every time stamp from the clock they are given,
never from the wall clock, so a simulated station can run faster than real
time with the same code path as a real one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """Station time in seconds since the clock's epoch."""

    def now_s(self) -> float: ...

    def sleep_s(self, duration_s: float) -> None: ...


class WallClock:
    """Real time (monotonic), for a real station."""

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now_s(self) -> float:
        return time.monotonic() - self._t0

    def sleep_s(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s)


class VirtualClock:
    """Virtual time running `speed` times faster than the wall clock.

    `advance_s` jumps time forward (used when everything waits on a known
    future event, such as a counter window that closes in 560 s); `sleep_s`
    waits the virtual duration, which takes duration/speed of wall time.
    Thread-safe: emulator threads and the engine share one instance.
    """

    def __init__(self, speed: float = 1.0, start_s: float = 0.0) -> None:
        if not speed > 0:
            raise ValueError(f"clock speed must be > 0, got {speed!r}")
        self.speed = float(speed)
        self._lock = threading.Lock()
        self._wall0 = time.monotonic()
        self._offset_s = float(start_s)

    def now_s(self) -> float:
        with self._lock:
            return self._offset_s + (time.monotonic() - self._wall0) * self.speed

    def advance_s(self, duration_s: float) -> None:
        if duration_s < 0:
            raise ValueError(f"cannot advance a clock backwards ({duration_s!r} s)")
        with self._lock:
            self._offset_s += duration_s

    def sleep_s(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s / self.speed)

    def set_speed(self, speed: float) -> None:
        """Run `speed` times faster than the wall clock from now on; time stays continuous."""
        if not speed > 0:
            raise ValueError(f"clock speed must be > 0, got {speed!r}")
        with self._lock:
            wall = time.monotonic()
            self._offset_s += (wall - self._wall0) * self.speed
            self._wall0 = wall
            self.speed = float(speed)


@contextmanager
def speed_at_most(clock: Clock, speed: float) -> Iterator[None]:
    """Inside the block station time runs at most `speed` times wall time.

    For work whose data must cross a real transport as it happens (a stretch
    of the 5 kHz grating stream): a fast VirtualClock slows down for it; a
    WallClock already runs at 1.
    """
    current = getattr(clock, "speed", 1.0)
    if not isinstance(clock, VirtualClock) or current <= speed:
        yield
        return
    clock.set_speed(speed)
    try:
        yield
    finally:
        clock.set_speed(current)
