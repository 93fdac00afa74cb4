"""A discrete-event station clock: time moves only when every party waits on it.

The parties are the threads that act in station time (the engine, a test's main
thread, a server's worker): each registers with `party(name)`. While any of them
runs, station time stands still; when the last one waits, the clock jumps to the
earliest due time (a timer of `call_at`/`call_every` or a waiter's timeout),
runs the timers due then in that waiting thread, in the order of their due times
and, at the same instant, of their creation, and wakes whoever's wait has ended.
So a simulated session depends on its seed and never on how busy the host is.

While no party is registered, time moves only to end a wait with a deadline
(a lone thread opening the station, a test): a thread that waits without one,
such as whoever waits for a run's end, never drives the station on by itself.
`station.clock.spawn_party` starts a thread already registered, so that time
cannot move between a thread's start and its registration.

A wait on which nothing can ever happen (every party waits, no timer is left,
no timeout is set) raises `ClockDeadlockError`, naming each party and what it waits on.
`ceiling` paces the clock to at most that many station seconds per wall second,
for watching a run live; without it time runs as fast as the CPU allows. A
`Pacemaker` makes a paced clock live: station time then flows on at that pace
whenever every other party waits, as a real station's does between sessions
and while a person acts on it (an emergency stop ramps the crank down).
The clock is its own link: a reply timeout counts station time exactly.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from station.clock import ClockCondition, ClockEvent, TimerHandle, TimerQueue, fire, spawn_party

PACE_STEP_WALL_S = 0.01  # a pacemaker's sleep, in wall time at the ceiling: what a live clock's idle steps last


class ClockDeadlockError(RuntimeError):
    """Every party waits and nothing can end a wait."""


class _Waiter:
    __slots__ = ("deadline_s", "on", "party", "woken")

    def __init__(self, party: _Party | None, deadline_s: float, on: object) -> None:
        self.party = party
        self.deadline_s = deadline_s
        self.woken = False
        self.on = on  # what it waits on: an event, a condition, or None (a sleep)


class _Party:
    __slots__ = ("name", "thread", "waiter")

    def __init__(self, name: str) -> None:
        self.name = name
        self.waiter: _Waiter | None = None
        self.thread = threading.current_thread()

    def waiting(self) -> bool:
        return self.waiter is not None and not self.waiter.woken


class EventClock:
    """Discrete-event time (see the module's docstring); thread-safe."""

    def __init__(self, start_s: float = 0.0, *, ceiling: float | None = None) -> None:
        if ceiling is not None and not ceiling > 0:
            raise ValueError(f"ceiling must be > 0 station seconds per wall second, got {ceiling!r}")
        self.ceiling = ceiling
        self._now_s = float(start_s)
        self._cv = threading.Condition(threading.Lock())
        self._timers = TimerQueue()
        self._parties: dict[int, _Party] = {}
        self._waiters: set[_Waiter] = set()
        self._advancing = False

    # ---- parties

    @contextmanager
    def party(self, name: str) -> Iterator[None]:
        """The calling thread acts in station time for the block: time waits for it."""
        ident = threading.get_ident()
        with self._cv:
            if ident in self._parties:
                raise RuntimeError(f"thread {threading.current_thread().name!r} is already a party of this clock")
            self._parties[ident] = _Party(name)
        try:
            yield
        finally:
            with self._cv:
                self._parties.pop(ident, None)  # gone already if dismissed
                self._advance_if_idle()

    def dismiss(self, thread: threading.Thread) -> None:
        """`thread` no longer holds station time (a party found stuck outside the clock, in a call that never
        returns): time goes on without it, as a real station's does around a hung process."""
        with self._cv:
            if self._parties.pop(thread.ident or 0, None) is not None:
                self._advance_if_idle()

    # ---- the Clock API

    def now_s(self) -> float:
        return self._now_s

    @property
    def link(self) -> EventClock:
        return self

    def link_s(self, duration_s: float) -> float:
        return duration_s

    @property
    def pace(self) -> float | None:
        return self.ceiling

    def sleep_s(self, duration_s: float) -> None:
        with self._cv:
            self._wait_until(lambda: False, self._now_s + max(duration_s, 0.0), None)

    def event(self) -> ClockEvent:
        return _Event(self)

    def condition(self, lock: Any = None) -> ClockCondition:
        return _Condition(self, lock if lock is not None else threading.RLock())

    def call_at(self, t_s: float, fn: Callable[[], object]) -> TimerHandle:
        return self._schedule(TimerHandle(max(float(t_s), self._now_s), fn, None))

    def call_every(self, period_s: float, fn: Callable[[], object]) -> TimerHandle:
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"call_every: period_s must be finite and > 0, got {period_s!r}")
        return self._schedule(TimerHandle(self._now_s + period_s, fn, float(period_s)))

    def _schedule(self, handle: TimerHandle) -> TimerHandle:
        with self._cv:
            self._timers.push(handle)
        return handle

    # ---- waiting and advancing (call with self._cv held)

    def _wait_until(self, ready: Callable[[], bool], deadline_s: float, on: object) -> bool:
        """Block until ready() (re-checked on every wake) or station time reaches deadline_s; ready()'s last value."""
        party = self._parties.get(threading.get_ident())
        while True:
            if ready():
                return True
            if self._now_s >= deadline_s:
                return False
            waiter = _Waiter(party, deadline_s, on)
            self._waiters.add(waiter)
            if party is not None:
                party.waiter = waiter
            try:
                self._advance_if_idle()
                while not waiter.woken and not ready():
                    self._cv.wait()
            finally:
                self._waiters.discard(waiter)
                if party is not None:
                    party.waiter = None
                else:  # a lone thread's ended wait may have been all that held time (see _idle)
                    self._advance_if_idle()

    def _wake(self, waiters: list[_Waiter]) -> None:
        for w in waiters:
            w.woken = True
        if waiters:
            self._cv.notify_all()

    def _wake_on(self, on: object) -> None:
        self._wake([w for w in self._waiters if w.on is on])

    def _idle(self) -> bool:
        """Every party waits, nobody is advancing, and no wait has ended whose thread has yet to run."""
        if self._advancing:
            return False
        for p in self._parties.values():  # a loop, not all() of a generator: this runs at every event
            if not p.waiting():
                return False
        return True not in [w.woken for w in self._waiters]

    def _advance_if_idle(self) -> None:
        """If every party waits, move time to the next due instant and run what is due there."""
        while self._waiters and self._idle():  # time moves only to end someone's wait
            due_s = min([w.deadline_s for w in self._waiters])
            if math.isinf(due_s) and not self._parties:
                return  # nobody acts in station time and no wait has a deadline: time stands still
            due_s = min(due_s, self._timers.next_due_s())
            if math.isinf(due_s):
                raise ClockDeadlockError(self._describe())
            self._advancing = True
            try:
                self._pace(due_s)
                self._now_s = max(self._now_s, due_s)
                self._run_due_timers()
            finally:
                self._advancing = False
            self._wake([w for w in self._waiters if w.deadline_s <= self._now_s])

    def _run_due_timers(self) -> None:
        while self._timers.next_due_s() <= self._now_s:
            handle = self._timers.pop()
            self._cv.release()
            try:
                fire(handle)
            finally:
                self._cv.acquire()
            if handle.period_s is not None and not handle.cancelled:
                handle.due_s += handle.period_s
                self._timers.push(handle)

    def _pace(self, due_s: float) -> None:
        """With a ceiling, a step of station time lasts at least step / ceiling of wall time (the parties' own
        work comes on top: the clock never races to catch up after they held it)."""
        if self.ceiling is None or due_s <= self._now_s:
            return
        self._cv.release()
        try:
            time.sleep((due_s - self._now_s) / self.ceiling)
        finally:
            self._cv.acquire()

    def _describe(self) -> str:
        waits = "; ".join(
            f"{p.name} (thread {p.thread.name}) waits on {_label(p.waiter.on) if p.waiter else 'nothing'}"
            for p in self._parties.values()
        )
        return f"station time {self._now_s:.6f} s: every party waits and nothing is due: {waits}"


class Pacemaker:
    """A party of a paced EventClock that only sleeps: station time never stands still (see the module)."""

    def __init__(self, clock: EventClock) -> None:
        if clock.ceiling is None:
            raise ValueError("a pacemaker needs a paced clock (EventClock(ceiling=...))")
        self._clock = clock
        self._step_s = PACE_STEP_WALL_S * clock.ceiling
        self._stopped = False
        self._thread = spawn_party(clock, "pacemaker", self._beat)

    def _beat(self) -> None:
        while not self._stopped:
            self._clock.sleep_s(self._step_s)

    def stop(self) -> None:
        """Leave the clock (within one step once the other parties wait)."""
        self._stopped = True
        self._thread.join()


def _label(on: object) -> str:
    return "a sleep" if on is None else getattr(on, "label", repr(on))


class _Event:
    def __init__(self, clock: EventClock, label: str = "") -> None:
        self._clock = clock
        self._flag = False
        self.label = f"event {label or hex(id(self))}"

    def is_set(self) -> bool:
        return self._flag

    def set(self) -> None:
        with self._clock._cv:
            self._flag = True
            self._clock._wake_on(self)

    def clear(self) -> None:
        self._flag = False

    def wait(self, *, timeout_s: float | None = None) -> bool:
        deadline_s = math.inf if timeout_s is None else self._clock.now_s() + timeout_s
        with self._clock._cv:
            return self._clock._wait_until(lambda: self._flag, deadline_s, self)


class _Condition:
    def __init__(self, clock: EventClock, lock: Any) -> None:
        self._clock = clock
        self._lock = lock
        self._notified: list[list[bool]] = []
        self.label = f"condition {hex(id(self))}"

    def __enter__(self) -> bool:
        return bool(self._lock.__enter__())

    def __exit__(self, *exc: Any) -> None:
        self._lock.__exit__(*exc)

    def wait(self, *, timeout_s: float | None = None) -> bool:
        box = [False]
        self._notified.append(box)
        deadline_s = math.inf if timeout_s is None else self._clock.now_s() + timeout_s
        self._lock.release()
        try:
            with self._clock._cv:
                return self._clock._wait_until(lambda: box[0], deadline_s, self)
        finally:
            self._lock.acquire()
            if box in self._notified:
                self._notified.remove(box)

    def wait_for(self, predicate: Callable[[], Any], *, timeout_s: float | None = None) -> Any:
        deadline_s = math.inf if timeout_s is None else self._clock.now_s() + timeout_s
        while not (result := predicate()):
            left_s = deadline_s - self._clock.now_s()
            if left_s <= 0:
                return result
            self.wait(timeout_s=None if math.isinf(left_s) else left_s)
        return result

    def notify(self, n: int = 1) -> None:
        with self._clock._cv:
            for box in self._notified[:n]:
                box[0] = True
            del self._notified[:n]
            self._clock._wake_on(self)

    def notify_all(self) -> None:
        self.notify(len(self._notified))
