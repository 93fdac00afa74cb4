"""Who owns time: one clock object per station, and every wait goes through it.

Drivers, emulators, the engine, the supervisor and the controller take their
time stamps from their clock and wait only on it: `sleep_s`, the events and
conditions of `event()` and `condition()`, whose timeouts count the clock's
seconds, and the timers of `call_at` and `call_every` (cancellable handles).
Nothing else in the production code reads `time.monotonic` or waits with a
timeout on a bare `threading` or `queue` object (tests/test_clock_discipline.py
reads the code and keeps it so).

Two clocks implement it today:

- `WallClock`: real time, for a real station (and for what a person waits on).
- `VirtualClock`: station time running `speed` times faster than the wall clock,
  for a simulated station.

`Clock.link` is the clock that times the link between host and devices:
protocol timeouts, heartbeats and their watchdogs, line pacing. On a real
station it is the clock itself. A wall-paced `VirtualClock` cannot make the
threads of the host answer at its pace (a 0.5 s reply timeout would be 0.5 ms
of wall time at 1000x), so its link is the wall clock, as the drivers and
emulators have always timed their links; a discrete-event clock, whose time
stands still while anyone works, is its own link.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Any, Protocol, runtime_checkable

log = logging.getLogger(__name__)


class TimerHandle:
    """A timer of `call_at` or `call_every`; `cancel()` stops it (idempotent, from any thread)."""

    __slots__ = ("cancelled", "due_s", "fn", "period_s")

    def __init__(self, due_s: float, fn: Callable[[], object], period_s: float | None) -> None:
        self.due_s = due_s
        self.fn = fn
        self.period_s = period_s
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class TimerQueue:
    """The pending timers of one clock, by due time and, at the same due time, in the order scheduled.
    Not thread-safe: its clock guards it."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, TimerHandle]] = []
        self._seq = itertools.count()

    def push(self, handle: TimerHandle) -> None:
        heapq.heappush(self._heap, (handle.due_s, next(self._seq), handle))

    def next_due_s(self) -> float:
        """The earliest live timer's due time, inf if none (cancelled timers are dropped as they surface)."""
        while self._heap and self._heap[0][2].cancelled:
            heapq.heappop(self._heap)
        return self._heap[0][0] if self._heap else math.inf

    def pop(self) -> TimerHandle:
        return heapq.heappop(self._heap)[2]


def fire(handle: TimerHandle) -> None:
    """Run a timer's function; its failure is logged and must not stop the clock's other timers."""
    try:
        handle.fn()
    except Exception:
        log.exception("clock timer %r failed", handle.fn)


class ClockEvent(Protocol):
    """threading.Event whose `wait` counts the clock's seconds."""

    def set(self) -> None: ...

    def clear(self) -> None: ...

    def is_set(self) -> bool: ...

    def wait(self, *, timeout_s: float | None = None) -> bool: ...


class ClockCondition(Protocol):
    """threading.Condition whose waits count the clock's seconds."""

    def __enter__(self) -> bool: ...

    def __exit__(self, *exc: object) -> None: ...

    def wait(self, *, timeout_s: float | None = None) -> bool: ...

    def wait_for(self, predicate: Callable[[], Any], *, timeout_s: float | None = None) -> Any: ...

    def notify(self, n: int = 1) -> None: ...

    def notify_all(self) -> None: ...


@runtime_checkable
class Clock(Protocol):
    """Station time in seconds since the clock's epoch, and the waits that count it."""

    def now_s(self) -> float: ...

    def sleep_s(self, duration_s: float) -> None: ...

    def event(self) -> ClockEvent: ...

    def condition(self, lock: Any = None) -> ClockCondition: ...

    def call_at(self, t_s: float, fn: Callable[[], object]) -> TimerHandle: ...

    def call_every(self, period_s: float, fn: Callable[[], object]) -> TimerHandle: ...

    @property
    def link(self) -> Clock: ...

    def party(self, name: str) -> AbstractContextManager[None]: ...

    def dismiss(self, thread: threading.Thread) -> None: ...

    def link_s(self, duration_s: float) -> float:
        """How many seconds of the clock's link `duration_s` of its time lasts (a reply timeout that covers
        a device's own station-time work)."""
        ...

    @property
    def pace(self) -> float | None:
        """At most this many of its seconds per wall second; None: as fast as the CPU allows."""
        ...


def spawn_party(clock: Clock, name: str, target: Callable[[], object]) -> threading.Thread:
    """Start a daemon thread that runs target() as a party of `clock` named `name` (station.event_clock);
    returns once it is registered, so that station time cannot move before the new thread takes part."""
    registered = threading.Event()

    def run() -> None:
        with clock.party(name):
            registered.set()
            target()

    thread = threading.Thread(target=run, name=name, daemon=True)
    thread.start()
    registered.wait()  # no timeout: the thread registers before anything else it does
    return thread


class _PacedClock:
    """A clock derived from the wall clock: `wall_s(d)` wall seconds last d of its seconds.

    Waits convert the remaining station time to wall time and look again when they
    wake (the pace may change, or time be advanced, while they wait). Timers run in
    one scheduler thread per clock, started with the first timer, in the order of
    their due times and, at the same due time, of their creation.
    """

    def __init__(self) -> None:
        self._timers = TimerQueue()
        self._timer_cond = threading.Condition()
        self._scheduler: threading.Thread | None = None

    def now_s(self) -> float:
        raise NotImplementedError

    def wall_s(self, duration_s: float) -> float:
        raise NotImplementedError

    def party(self, name: str) -> AbstractContextManager[None]:
        """A paced clock's time moves by itself: a party changes nothing."""
        return nullcontext()

    def dismiss(self, thread: threading.Thread) -> None:
        """Nothing to dismiss: time moves by itself."""

    def link_s(self, duration_s: float) -> float:
        return self.wall_s(duration_s)  # its link is the wall clock

    def sleep_s(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(self.wall_s(duration_s))

    def event(self) -> ClockEvent:
        return _PacedEvent(self)

    def condition(self, lock: Any = None) -> ClockCondition:
        return _PacedCondition(self, lock)

    # ---- timers

    def call_at(self, t_s: float, fn: Callable[[], object]) -> TimerHandle:
        """Run fn() once at station time t_s (at once if that has passed), in the clock's timer thread."""
        return self._schedule(TimerHandle(float(t_s), fn, None))

    def call_every(self, period_s: float, fn: Callable[[], object]) -> TimerHandle:
        """Run fn() every period_s from now + period_s on, on that grid; a timer that fell more than a
        period behind (a stalled host) restarts its grid from now instead of running a burst."""
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"call_every: period_s must be finite and > 0, got {period_s!r}")
        return self._schedule(TimerHandle(self.now_s() + period_s, fn, float(period_s)))

    def _schedule(self, handle: TimerHandle) -> TimerHandle:
        with self._timer_cond:
            self._timers.push(handle)
            if self._scheduler is None:
                self._scheduler = threading.Thread(target=self._run_timers, name="clock-timers", daemon=True)
                self._scheduler.start()
            self._timer_cond.notify()
        return handle

    def _run_timers(self) -> None:
        while True:
            with self._timer_cond:
                due_s = self._timers.next_due_s()
                if math.isinf(due_s):
                    self._timer_cond.wait()
                    continue
                left_s = due_s - self.now_s()
                if left_s > 0:
                    self._timer_cond.wait(self.wall_s(left_s))
                    continue
                handle = self._timers.pop()
            fire(handle)
            if handle.period_s is not None and not handle.cancelled:
                due_s += handle.period_s
                now_s = self.now_s()
                if due_s <= now_s - handle.period_s:
                    due_s = now_s + handle.period_s
                handle.due_s = due_s
                with self._timer_cond:
                    self._timers.push(handle)


class _PacedEvent:
    def __init__(self, clock: _PacedClock) -> None:
        self._clock = clock
        self._event = threading.Event()
        self.set, self.clear, self.is_set = self._event.set, self._event.clear, self._event.is_set

    def wait(self, *, timeout_s: float | None = None) -> bool:
        if timeout_s is None:
            return self._event.wait()
        deadline_s = self._clock.now_s() + timeout_s
        while True:
            left_s = deadline_s - self._clock.now_s()
            if left_s <= 0:
                return self._event.is_set()
            if self._event.wait(self._clock.wall_s(left_s)):
                return True


class _PacedCondition:
    def __init__(self, clock: _PacedClock, lock: Any) -> None:
        self._clock = clock
        self._cond = threading.Condition(lock)
        self.notify, self.notify_all = self._cond.notify, self._cond.notify_all

    def __enter__(self) -> bool:
        return self._cond.__enter__()

    def __exit__(self, *exc: Any) -> None:
        self._cond.__exit__(*exc)

    def wait(self, *, timeout_s: float | None = None) -> bool:
        if timeout_s is None:
            return self._cond.wait()
        return self._cond.wait(self._clock.wall_s(max(timeout_s, 0.0)))

    def wait_for(self, predicate: Callable[[], Any], *, timeout_s: float | None = None) -> Any:
        if timeout_s is None:
            return self._cond.wait_for(predicate)
        deadline_s = self._clock.now_s() + timeout_s
        while not (result := predicate()):
            left_s = deadline_s - self._clock.now_s()
            if left_s <= 0:
                return result
            self._cond.wait(self._clock.wall_s(left_s))
        return result


class WallClock(_PacedClock):
    """Real time (monotonic), for a real station; its own link."""

    def __init__(self) -> None:
        super().__init__()
        self._t0 = time.monotonic()

    def now_s(self) -> float:
        return time.monotonic() - self._t0

    def wall_s(self, duration_s: float) -> float:
        return duration_s

    @property
    def pace(self) -> float:
        return 1.0

    @property
    def link(self) -> WallClock:
        return self


_HOST_CLOCK = WallClock()


def host_clock() -> WallClock:
    """The host's wall clock: what a person waits on (console refresh, panel sessions) and the link of a
    wall-paced VirtualClock. One per process, so that its timers share one thread."""
    return _HOST_CLOCK


def utc_s() -> float:
    """The host's UTC time in seconds since the Unix epoch: a time stamp another host can compare with its own
    (the control channel's freshness), never a duration or a wait."""
    return time.time()


class VirtualClock(_PacedClock):
    """Virtual time running `speed` times faster than the wall clock.

    `advance_s` jumps time forward (used when everything waits on a known
    future event, such as a counter window that closes in 560 s); `sleep_s`
    waits the virtual duration, which takes duration/speed of wall time.
    Thread-safe: emulator threads and the engine share one instance. Its link is
    the host's wall clock (see the module's docstring).
    """

    def __init__(self, speed: float = 1.0, start_s: float = 0.0) -> None:
        super().__init__()
        if not speed > 0:
            raise ValueError(f"clock speed must be > 0, got {speed!r}")
        self.speed = float(speed)
        self._lock = threading.Lock()
        self._wall0 = time.monotonic()
        self._offset_s = float(start_s)

    def now_s(self) -> float:
        with self._lock:
            return self._offset_s + (time.monotonic() - self._wall0) * self.speed

    def wall_s(self, duration_s: float) -> float:
        return duration_s / self.speed

    @property
    def pace(self) -> float:
        return self.speed

    @property
    def link(self) -> WallClock:
        return _HOST_CLOCK

    def advance_s(self, duration_s: float) -> None:
        if duration_s < 0:
            raise ValueError(f"cannot advance a clock backwards ({duration_s!r} s)")
        with self._lock:
            self._offset_s += duration_s
        with self._timer_cond:
            self._timer_cond.notify()
