"""One supervisor of motion: whatever ends a run, every moving device reaches a safe state within a stated time.

The supervisor lives as long as its station's controller, in a thread of its own
that ticks every `TICK_S` of wall time. Three things go through it:

- every safe stop (`safe_state`): a run that finishes, fails or is aborted calls it
  from the engine thread. `hw.safe_stop()` (window aborted, crank ramped to rest and
  disabled, further moving devices stopped) runs in a helper thread and gets
  `bound_s` of wall time; if it raises or overruns, `hw.emergency_stop()` follows
  (crank quick-stopped, head stopped and held). A safe state is therefore reached
  within bound_s + `QUICK_STOP_BOUND_S` whatever the drivers do (each of their waits
  is bounded too); the SafeState record says which way and how long it took.
- the engine thread (`watch`): if it ends without `release()` (an exception the
  engine did not handle, a thread lost), or does not end within `ABORT_GRACE_S` of
  an abort or signal (`expect_end`), the supervisor brings the devices to a safe
  state itself (a dead engine: safe stop, then everything stopped and held; a
  stuck one: an emergency stop at once, since it may still hold the counter's
  port) and calls the run's `on_lost`, so that the outcome is recorded and whoever
  waits on the run is released. That work runs in a thread of its own: the tick
  never blocks (a locked store must not silence the heartbeat).
- the master heartbeat (`HeartbeatSource.tie_heartbeat`): the station's drive hears
  the master only while `alive()` holds, i.e. while this thread ticks. A hung or
  dead supervisor falls silent, and the drive, configured to stop on its own when
  its master is lost (CiA 402 0x6007, 0x605A), stops the crank: a live process
  whose supervision is gone no longer defeats the drive's watchdog.

Clocks: the tick, alive(), the abort grace and the wait for a lost run's record count the host's
wall time (they judge the process, whatever the station's clock); a safe stop's bound counts the
station clock's link (wall time on a real and on a wall-paced simulated station, station time on the
discrete-event one), and its helper thread is a party of the station clock (station.clock.spawn_party).
Bounds: tick 0.05 s; alive() false once a tick has been stuck for STALE_S = 1 s (a thread that only
waits its turn on a busy host is not hung); the drive's consumer then trips after 3 heartbeat
periods (1.5 s on the simulated station).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from station.clock import Clock, ClockEvent, host_clock, spawn_party

log = logging.getLogger(__name__)

TICK_S = 0.05  # wall seconds between supervisor ticks
STALE_S = 1.0  # a supervisor stuck this long in one tick is not alive (its heartbeat stops)
DEFAULT_SAFE_STOP_BOUND_S = 10.0  # wall seconds for hw.safe_stop() if the station states none
QUICK_STOP_BOUND_S = 2.0  # wall seconds an emergency stop may take after a safe stop overran
ABORT_GRACE_S = 5.0  # wall seconds an engine gets to end after an abort before the supervisor stops motion itself


@runtime_checkable
class HeartbeatSource(Protocol):
    """A station whose master heartbeat (or equivalent keep-alive) can be tied to a liveness test."""

    def tie_heartbeat(self, alive: Callable[[], bool]) -> None: ...


@runtime_checkable
class StatesStopBound(Protocol):
    """A station that states how long its safe stop may take (wall seconds)."""

    def safe_stop_bound_s(self) -> float: ...


@dataclass(frozen=True)
class SafeState:
    """How a safe state was reached: `safe stop` or `emergency stop`, in how many wall seconds, and why."""

    reason: str
    how: str
    took_s: float
    errors: tuple[str, ...] = ()

    def describe(self) -> str:
        extra = f"; {'; '.join(self.errors)}" if self.errors else ""
        return f"safe state by {self.how} in {self.took_s:.2f} s ({self.reason}){extra}"


@dataclass
class _Watch:
    thread: threading.Thread
    on_lost: Callable[[str, SafeState], None]
    lost: ClockEvent
    released: bool = False
    deadline_s: float | None = None
    handled: bool = False


class MotionSupervisor:
    """The one supervisor of motion of a station (thread-safe)."""

    def __init__(
        self,
        hardware: Any,
        *,
        bound_s: float | None = None,
        abort_grace_s: float = ABORT_GRACE_S,
        clock: Clock | None = None,
    ) -> None:
        self.hw = hardware
        self._station_clock = clock if clock is not None else host_clock()
        self._clock = self._station_clock.link  # the safe stops' bounds: the pace of the drivers' confirmations
        self._tick_clock = host_clock()  # liveness is the host process's: ticks, staleness, grace, records
        if bound_s is None:
            bound_s = hardware.safe_stop_bound_s() if isinstance(hardware, StatesStopBound) else None
        self.bound_s = DEFAULT_SAFE_STOP_BOUND_S if bound_s is None else float(bound_s)
        self.abort_grace_s = abort_grace_s
        self.last: SafeState | None = None
        self._lock = threading.Lock()
        self._watch: _Watch | None = None
        self._stop = self._tick_clock.event()
        self._ended = self._tick_clock.event()
        self._frozen = threading.Event()
        self._tick_started_s: float | None = None  # set while a tick runs
        self._thread = threading.Thread(target=self._loop, name="motion-supervisor", daemon=True)

    # ---- life cycle ---------------------------------------------------------------------

    def start(self) -> MotionSupervisor:
        self._thread.start()
        if isinstance(self.hw, HeartbeatSource):
            self.hw.tie_heartbeat(self.alive)
        return self

    def close(self) -> None:
        """A deliberate end: the heartbeat is handed back to the station (no lost master), the thread stops."""
        if isinstance(self.hw, HeartbeatSource):
            self.hw.tie_heartbeat(lambda: True)
        self._stop.set()
        if self._thread.is_alive():
            self._ended.wait(timeout_s=1.0)

    def alive(self) -> bool:
        """The supervisor ticks: its thread runs and no tick has been stuck for STALE_S."""
        started_s = self._tick_started_s
        return self._thread.is_alive() and (started_s is None or self._tick_clock.now_s() - started_s < STALE_S)

    def freeze(self) -> None:
        """Hang in the next tick without ending the thread: what a hung supervisor looks like (for fault tests)."""
        self._frozen.set()

    # ---- runs ---------------------------------------------------------------------------

    def watch(self, thread: threading.Thread, on_lost: Callable[[str, SafeState], None]) -> None:
        """Supervise a run's engine thread until release(); on_lost(reason, safe_state) if it is lost."""
        with self._lock:
            self._watch = _Watch(thread, on_lost, lost=self._tick_clock.event())

    def release(self, thread: threading.Thread | None = None) -> None:
        """The run ended through its own path (its outcome recorded, its devices stopped)."""
        with self._lock:
            w = self._watch
            if w is not None and (thread is None or w.thread is thread):
                w.released = True
                self._watch = None

    def expect_end(self, within_s: float | None = None) -> None:
        """An abort or signal was sent: the run must end within within_s (default ABORT_GRACE_S) of wall time."""
        with self._lock:
            if self._watch is not None and self._watch.deadline_s is None:
                self._watch.deadline_s = self._tick_clock.now_s() + (
                    self.abort_grace_s if within_s is None else within_s
                )

    def wait_lost(self, *, timeout_s: float) -> bool:
        """True once a watched run was found lost and its devices brought to a safe state (for tests)."""
        w = self._watch
        return w.lost.wait(timeout_s=timeout_s) if w is not None else False

    # ---- safe states ----------------------------------------------------------------------

    def safe_state(self, reason: str) -> SafeState:
        """hw.safe_stop() within bound_s, else (or if it raises) hw.emergency_stop(); the record of which."""
        t0 = self._clock.now_s()
        errors: list[str] = []
        ended = self._clock.event()

        def stop() -> None:
            try:
                self.hw.safe_stop()
            except Exception as exc:  # any failure of the ramp is answered by the quick stop below
                errors.append(f"safe stop failed: {type(exc).__name__}: {exc}")
            finally:
                ended.set()

        spawn_party(self._station_clock, "safe-stop", stop)  # it acts in station time: time waits for it
        if ended.wait(timeout_s=self.bound_s) and not errors:
            state = SafeState(reason, "safe stop", self._clock.now_s() - t0, tuple(errors))
        else:
            if not ended.is_set():
                errors.append(f"safe stop not done within {self.bound_s:g} s")
            state = self._emergency(reason, t0, errors)
        self.last = state
        log.info("%s", state.describe())
        return state

    def emergency_state(self, reason: str) -> SafeState:
        """hw.emergency_stop() now (motion only; callable from any thread); its record."""
        state = self._emergency(reason, self._clock.now_s(), [])
        self.last = state
        return state

    def _emergency(self, reason: str, t0: float, errors: list[str]) -> SafeState:
        try:
            self.hw.emergency_stop()
        except Exception as exc:  # the stops of every device are best effort; say what failed
            errors.append(f"emergency stop: {type(exc).__name__}: {exc}")
        return SafeState(reason, "emergency stop", self._clock.now_s() - t0, tuple(errors))

    # ---- the tick -----------------------------------------------------------------------------

    def _loop(self) -> None:
        try:
            while not self._stop.wait(timeout_s=TICK_S):
                self._tick_started_s = self._tick_clock.now_s()
                if self._frozen.is_set():
                    self._stop.wait()  # hung: the tick never ends
                    return
                try:
                    self._tick()
                except Exception:  # the supervisor must outlive any of its own errors
                    log.exception("motion supervisor tick failed")
                self._tick_started_s = None
        finally:
            self._ended.set()

    def _tick(self) -> None:
        with self._lock:
            w = self._watch
            if w is None or w.handled or w.released:
                return
            if not w.thread.is_alive():
                reason = f"engine thread {w.thread.name!r} ended without recording its outcome"
            elif w.deadline_s is not None and self._tick_clock.now_s() > w.deadline_s:
                reason = f"engine did not end within {self.abort_grace_s:g} s of an abort"
            else:
                return
            w.handled = True
        threading.Thread(target=self._on_lost, args=(w, reason), name="supervisor-safe-state", daemon=True).start()

    def _on_lost(self, w: _Watch, reason: str) -> None:
        log.error("motion supervisor: %s", reason)
        if w.thread.is_alive():  # stuck, perhaps holding the counter's port: motion only, at once
            self._station_clock.dismiss(w.thread)  # a stuck engine holds no station time (station.event_clock)
            state = self.emergency_state(reason)
        else:  # gone: the window is aborted and the crank ramped, then everything is stopped and held
            state = self.safe_state(reason)
            held = self._emergency(reason, self._clock.now_s(), list(state.errors))
            state = SafeState(reason, f"{state.how}, then held", state.took_s + held.took_s, held.errors)
            self.last = state
        try:
            w.on_lost(reason, state)
        except Exception:  # the devices are safe; the record is what failed
            log.exception("motion supervisor: recording the lost run failed")
        finally:
            w.lost.set()
