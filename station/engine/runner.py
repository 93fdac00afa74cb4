"""The run engine: one procedure at a time through the station's drivers, every measurement stored durably.

State machine: idle -> running <-> pausing -> paused -> running ... ->
finished | aborted | estopped | failed. A pause takes effect at safe points
(before each measurement, and at Checkpoint steps). An abort takes effect at
the next event of the open window (the counter is aborted, the table ramps
to rest). An emergency stop acts at once from the calling thread (quick stop
of the crank, the head stopped and held, the window aborted), then the
procedure ends. Each finished measurement is committed to the store before
the next step starts, so a fault or a kill loses no finished measurement;
`run(..., resume_uid=...)` hands the procedure the measurements a session
already holds instead of measuring them again.

Whatever ends a run, its devices reach a safe state through the station's one
supervisor of motion (station.engine.supervisor), within the bound it states, and the
outcome is recorded: an unexpected exception (a locked store, a bug in a step)
fails the run like a device fault, never skips the stop. A run holds its
session's lock (station.session_lock) from before the session exists, or before a
resume reads it, until its outcome is written: one process per session.

Fault policy during a measurement (bluesky's suspenders, at point granularity):
- a TransientFault (a garbled or CRC-failed counter or grating frame, a grating
  stretch that kept losing samples) repeats the point, at most POINT_REPEATS times,
  once the window is aborted (nothing of the failed attempt is stored);
- every other fault (drive fault, bus-off, heartbeat or SDO loss, a port gone, a
  read head's signal loss, a counter overflow, a locked store) ends the session
  `failed`, devices safe, every finished point kept, resumable.

The engine is also the `RunContext` that steps run in.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from typing import Any, NamedTuple

import numpy as np

from station.clock import host_clock
from station.engine.planning import Plan
from station.engine.protocols import Event, StationHardware
from station.engine.registry import ProcedureSpec
from station.engine.steps import Recorded, Step
from station.engine.supervisor import MotionSupervisor
from station.engine.timing import TimingFault
from station.errors import DeviceError, TransientFault
from station.provenance import make_provenance
from station.session import Measurement, PointRecord
from station.session_lock import SessionLock, creating
from station.store import SessionStore
from station.telemetry import envelope


class State(StrEnum):
    IDLE = "idle"
    RUNNING = "running"
    WAITING_OPERATOR = "waiting_operator"
    PAUSING = "pausing"
    PAUSED = "paused"
    ABORTING = "aborting"
    FINISHED = "finished"
    ABORTED = "aborted"
    ESTOPPED = "estopped"
    FAILED = "failed"


FINAL_STATES = (State.FINISHED, State.ABORTED, State.ESTOPPED, State.FAILED)
STORE_STATUS = {State.FINISHED: "finished", State.ABORTED: "aborted", State.ESTOPPED: "aborted", State.FAILED: "failed"}


class StopCount(NamedTuple):
    """How many aborts and emergency stops an engine has been asked for so far (never reset).

    A run is handed the count as of its request (`Engine.run(stops_seen=...)`): every stop requested after that
    moment is the run's own and ends it, however early it came (while the session was being created, before its
    first step); stops requested before belong to what ran before."""

    aborts: int
    estops: int


class Aborted(Exception):  # noqa: N818 - a control-flow signal, not an error
    """Raised inside the engine thread when an abort or emergency stop was requested."""


@dataclass
class Progress:
    state: State = State.IDLE
    session_uid: str = ""
    procedure: str = ""
    key: str = ""
    done: int = 0
    total: int = 0
    estimate_total_s: float = 0.0
    estimate_remaining_s: float = 0.0  # of the measurements not yet finished
    in_step_s: float = 0.0  # station time spent on the measurement under way, up to its estimate
    elapsed_s: float = 0.0
    faults: list[str] = field(default_factory=list)

    @property
    def fraction(self) -> float:
        if self.estimate_total_s <= 0:
            return 0.0
        left = self.estimate_remaining_s - self.in_step_s
        return min(1.0, max(0.0, 1.0 - left / self.estimate_total_s))

    @property
    def eta_s(self) -> float:
        """Station seconds left by the dry run's estimates."""
        return max(self.estimate_remaining_s - self.in_step_s, 0.0)

    def to_json(self) -> dict:
        return asdict(self) | {"state": str(self.state), "fraction": self.fraction, "eta_s": self.eta_s}


Publisher = Callable[[str, dict], None]
POINT_REPEATS = 2  # a point that meets a transient fault is measured again at most this many times
log = logging.getLogger(__name__)
WINDOW_PUBLISH_WALL_S = 0.1  # window progress and trace at most 10 times per wall second (the host's)
TRACE_POINTS = 250  # samples per trace message, at most


class Engine:
    """Runs procedures on a station; control calls are thread-safe."""

    def __init__(
        self,
        hardware: StationHardware,
        store: SessionStore,
        publish: Publisher | None = None,
        supervisor: MotionSupervisor | None = None,
    ) -> None:
        self.hw = hardware
        self.supervisor = supervisor or MotionSupervisor(hardware, clock=hardware.clock)
        self.clock = hardware.clock
        self.store = store
        self.operator: str | None = None  # who starts the runs (the panel's user, --operator); None: the OS user
        self.customer: str | None = None  # whose instrument the runs calibrate (--customer)
        self.publish: Publisher = publish or (lambda topic, msg: None)
        self.watched = publish is not None  # someone reads the telemetry: windows stream a display trace
        self.progress = Progress()
        self._lock = threading.Lock()
        self._resume = threading.Event()
        self._resume.set()
        self._acknowledged = self.clock.link.event()  # a person acknowledges: waited on the link's (wall) time
        self._pause_requested = False
        self._abort_requested = False
        self._estop = False
        self._aborts = 0  # every abort ever requested (StopCount): a run knows which stops came after its request
        self._estops = 0
        self.position_deg: float | None = None
        self.freq_hz = 0.0
        self.t0_s = 0.0
        self.sequence = 0
        self._session_uid = ""
        self._estimates: dict[str, float] = {}
        self._step_started_s = 0.0
        self._session_lock: SessionLock | None = None

    # ---- control, from any thread ---------------------------------------------------------

    def pause(self) -> None:
        with self._lock:
            if self.progress.state == State.RUNNING:
                self._pause_requested = True
                self._set_state(State.PAUSING)

    def resume(self) -> None:
        with self._lock:
            self._pause_requested = False
            if self.progress.state in (State.PAUSING, State.PAUSED):
                self._set_state(State.RUNNING)
            self._resume.set()

    def abort(self) -> None:
        with self._lock:
            self._aborts += 1
            self._abort_requested = True
            if self.progress.state in (State.RUNNING, State.PAUSING, State.PAUSED, State.WAITING_OPERATOR):
                self._set_state(State.ABORTING)
            self._resume.set()

    def acknowledge(self) -> None:
        """The operator has done what the open OperatorAction asked."""
        self._acknowledged.set()

    def emergency_stop(self) -> None:
        """Quick-stop the crank and hold the head now, then end the procedure.

        The flags go up first, so that any device error the stop causes in the engine's own thread
        is read as the stop's consequence, not as a fault of the run."""
        with self._lock:
            self._estops += 1
            self._estop = True
            self._abort_requested = True
            self._resume.set()
        self.hw.emergency_stop()
        self.publish("fault", {"kind": "estop", "message": "emergency stop"})

    def stop_count(self) -> StopCount:
        """The stops requested so far; read without the lock (a control thread must never wait on a run's store
        writes): a stop being counted at this moment is seen or not, and either is a valid order of the two."""
        return StopCount(self._aborts, self._estops)

    # ---- RunContext: what steps use --------------------------------------------------------

    def check_abort(self) -> None:
        if self._abort_requested:
            raise Aborted("emergency stop" if self._estop else "abort requested")

    def safe_point(self) -> None:
        """A pause requested before now takes effect here; an abort ends the run here."""
        self.check_abort()
        with self._lock:
            if self._pause_requested:
                self._pause_requested = False
                self._resume.clear()
                self._set_state(State.PAUSED)
        self._resume.wait()
        self.check_abort()

    def event(self, kind: str, message: str, level: str = "info") -> None:
        if self._session_uid:
            self.store.add_event(self._session_uid, kind, message, level)
        self.publish("event", {"kind": kind, "message": message, "level": level})

    def set_table(self, freq_hz: float, settle_s: float = 0.0) -> float:
        """Ramp the table to freq_hz (if it is not there), then settle; the drive's frequency."""
        measured = freq_hz
        if freq_hz != self.freq_hz:
            measured = self.hw.set_vibration(freq_hz).freq_hz
            self.freq_hz = freq_hz
            self.publish("motion", {"freq_hz": measured, "commanded_hz": freq_hz, "index_deg": self.position_deg})
        self.wait_s(settle_s)
        return measured

    def move_head(self, position_deg: float) -> float:
        """Move the indexing head, bringing the table to rest first; the settled angle."""
        if self.position_deg is not None and abs(position_deg - self.position_deg) < 1e-9:
            return self.position_deg
        self.set_table(0.0)
        self.position_deg = self.hw.move_index(position_deg)
        self.publish("motion", {"freq_hz": 0.0, "commanded_hz": 0.0, "index_deg": self.position_deg})
        return self.position_deg

    def ask_operator(self, message: str, action: dict) -> None:
        """Publish the request and wait for the operator (a simulated station's operator acts on `action`)."""
        self._acknowledged.clear()
        self.event("operator", message)
        self.publish("prompt", {"message": message, "action": action})
        operator = getattr(self.hw, "operator", None)
        if operator is not None:
            operator.perform(message, action)
            return
        self._set_state(State.WAITING_OPERATOR)
        while not self._acknowledged.wait(timeout_s=0.1):
            self.check_abort()
        self.check_abort()
        self._set_state(State.RUNNING)

    def wait_s(self, duration_s: float) -> None:
        """Wait station time, in slices so that an abort is seen within a second of station time."""
        end_s = self.clock.now_s() + duration_s
        while (left := end_s - self.clock.now_s()) > 0:
            self.check_abort()
            self.clock.sleep_s(min(left, 1.0))

    def window_monitor(self, key: str, preset_pulses: int) -> Callable[[Event], None]:
        """The on_event callback of a counter window: abort checks and throttled progress telemetry."""
        expected_s = self._estimates.get(key, math.nan)
        opened_s: list[float] = []
        last_wall = [-math.inf]

        def on_event(ev: Event) -> None:
            self.check_abort()
            if ev.kind == "open":
                opened_s.append(ev.t_s)
            now = host_clock().now_s()  # what a person watching sees: wall time, whatever the clock
            if ev.kind not in ("open", "close") and now - last_wall[0] < WINDOW_PUBLISH_WALL_S:
                return
            last_wall[0] = now
            elapsed = ev.t_s - opened_s[0] if opened_s and math.isfinite(ev.t_s) else 0.0
            fraction = min(elapsed / expected_s, 1.0) if expected_s > 0 else 0.0
            msg = {"session_uid": self._session_uid, "key": key, "event": ev.kind, "elapsed_s": elapsed,
                   "expected_s": expected_s, "preset_pulses": preset_pulses,
                   "pulses_est": round(fraction * preset_pulses)}  # fmt: skip
            if ev.kind == "close" and elapsed > 0:
                msg["rate_radps"] = 2 * math.pi * ev.value / (self.hw.station.pulses_per_rev * elapsed)
            self.publish("window", msg)
            self._publish_progress()

        return on_event

    def trace_sink(self) -> Callable | None:
        """The on_trace callback of a window: grating samples published as a decimated displacement trace;
        None when nobody watches (no publisher): the grating then stays quiet between its stretches."""
        if not self.watched:
            return None
        t_parts: list = []
        z_parts: list = []
        last_wall = [-math.inf]

        def on_trace(t_s, z_m) -> None:
            t_parts.append(t_s)
            z_parts.append(z_m)
            now = host_clock().now_s()  # what a person watching sees: wall time, whatever the clock
            if now - last_wall[0] < WINDOW_PUBLISH_WALL_S:
                return
            last_wall[0] = now
            t, z = np.concatenate(t_parts), np.concatenate(z_parts)
            t_parts.clear()
            z_parts.clear()
            t, z = envelope(t, z, TRACE_POINTS // 2)  # min and max per bucket: the motion's true envelope
            self.publish("trace", {"session_uid": self._session_uid, "t_s": t, "z_m": z, "freq_hz": self.freq_hz})

        return on_trace

    # ---- internals ----------------------------------------------------------------------------

    def _set_state(self, state: State) -> None:
        self.progress.state = state
        self.publish("state", {"state": str(state), "session_uid": self._session_uid,
                               "procedure": self.progress.procedure})  # fmt: skip
        if self._session_uid:
            try:  # a control call (abort, pause) must not fail on a store that cannot take its event
                self.store.add_event(self._session_uid, "state", str(state))
            except Exception as exc:
                log.error("state %s not recorded: %s: %s", state, type(exc).__name__, exc)

    def _publish_progress(self) -> None:
        p = self.progress
        now = self.clock.now_s()
        p.elapsed_s = now - self.t0_s
        p.in_step_s = min(max(now - self._step_started_s, 0.0), self._estimates.get(p.key, 0.0)) if p.key else 0.0
        self.publish("progress", p.to_json())

    def _store(self, out: Any) -> Any:
        """Commit a measurement before anything else happens; what the procedure receives."""
        if isinstance(out, Recorded):
            self.store.add_point(self._session_uid, out.record, out.raw)
            self.sequence += 1
            self.publish("point", asdict(out.record))
            return out.record
        if isinstance(out, Measurement):
            self.store.add_measurement(self._session_uid, out)
            self.publish("measurement", {"key": out.key, "kind": out.kind, "values": out.values})
            return out
        raise TypeError(f"a measuring step returned {type(out).__name__}, not Recorded or Measurement")

    def _execute(self, step: Step, done: dict[str, Any]) -> Any:
        self.check_abort()  # before every step, moving ones too: a stop requested before the first one ends the run
        key = step.key
        if key is None:
            return step.run(self)
        self.safe_point()
        if key in done:
            return done[key]
        self.progress.key = key
        self._step_started_s = self.clock.now_s()
        self._publish_progress()
        result = self._store(self._measure(step))
        done[key] = result
        self.progress.done += 1
        self.progress.estimate_remaining_s -= self._estimates.get(key, 0.0)
        self.progress.key = ""
        self._publish_progress()
        return result

    def _measure(self, step: Step) -> Any:
        """One measuring step; a transient fault repeats it (the policy in the module docstring)."""
        for attempt in range(POINT_REPEATS + 1):
            try:
                return step.run(self)
            except TransientFault as exc:
                if self._abort_requested or attempt == POINT_REPEATS:
                    raise
                msg = f"{step.key}: {type(exc).__name__}: {exc}; measuring it again ({attempt + 1} of {POINT_REPEATS})"
                self.event("repeat", msg, "warning")
                self.publish("fault", {"kind": "repeat", "message": msg})
        raise AssertionError("unreachable")

    def provenance(self, instrument_serial: str) -> dict[str, Any]:
        """Where a new session comes from (station.provenance): the station file's id, simulated or real, the
        seed, the operator; ProvenanceError on a real station without an instrument serial number."""
        cfg = getattr(self.hw, "config", None)
        return make_provenance(
            station_id=getattr(cfg, "station_id", "") or "unknown", simulated=bool(getattr(cfg, "simulated", True)),
            instrument_serial=instrument_serial, seed=getattr(self.hw, "seed", None), operator=self.operator,
            customer=self.customer,
        )  # fmt: skip

    def _open_session(self, spec: ProcedureSpec, plan: Plan, serial: str, resume_uid: str | None, config: dict) -> dict:
        if resume_uid is None:
            cfg = {"procedure": spec.name, "params": plan.params, "plan": plan.to_json()} | config
            with creating(self.store.path):  # created and locked at once: never taken for an interrupted one
                self._session_uid = self.store.create_session(
                    self.hw.station, spec.name, instrument_serial=serial, config=cfg, provenance=self.provenance(serial)
                )
                self._session_lock = SessionLock(self.store.path, self._session_uid)
            self.sequence = 0
            return {}
        self._session_lock = SessionLock(self.store.path, resume_uid)  # SessionLocked for a second process
        self._session_uid = resume_uid
        session = self.store.load_session(resume_uid, with_raw=False)
        done: dict[str, Any] = {p.point_id: p for p in session.points}
        done |= {m.key: m for m in session.measurements}
        self.sequence = max((p.sequence + 1 for p in session.points), default=0)
        self.store.set_status(resume_uid, "running")
        self.event("resume", f"resuming with {len(done)} measurements already stored")
        return done

    def run(
        self,
        spec: ProcedureSpec,
        plan: Plan,
        *,
        instrument_serial: str = "",
        resume_uid: str | None = None,
        config: dict | None = None,
        on_open: Callable[[str], None] | None = None,
        stops_seen: StopCount | None = None,
    ) -> tuple[str, Any]:
        """Run a validated plan's procedure; (session uid, the procedure's return value).

        `on_open(uid)` is called once the session exists in the store, before anything moves. `stops_seen`: the
        stop_count() when the run was requested (default: now); an abort or emergency stop requested since then
        ends the run before its next step, the first one included, and its outcome is recorded like any other.
        """
        self._arm(self.stop_count() if stops_seen is None else stops_seen)
        self.progress = Progress(procedure=spec.name)
        self._session_uid = ""
        try:
            done = self._open_session(spec, plan, instrument_serial, resume_uid, config or {})
        except BaseException:
            self._release_lock()
            raise
        try:
            return self._run_open(spec, plan, done, on_open)
        finally:
            self._release_lock()

    def _arm(self, seen: StopCount) -> None:
        """A new run: the stop flags say whether a stop was requested after `seen`, never simply cleared (a stop
        that came between the run's request and this moment would be lost; one before it is the last run's)."""
        with self._lock:
            self._estop = self._estops != seen.estops
            self._abort_requested = self._estop or self._aborts != seen.aborts
            self._pause_requested = False
            self._resume.set()

    def _release_lock(self) -> None:
        if self._session_lock is not None:
            self._session_lock.release()
            self._session_lock = None

    def _run_open(
        self, spec: ProcedureSpec, plan: Plan, done: dict[str, Any], on_open: Callable[[str], None] | None
    ) -> tuple[str, Any]:
        if on_open is not None:
            on_open(self._session_uid)
        self._estimates = plan.key_estimates_s()
        last_s = max((p.start_s + p.Tm_s for p in done.values() if isinstance(p, PointRecord)), default=0.0)
        self.t0_s = self.clock.now_s() - last_s
        p = self.progress
        p.session_uid, p.total, p.done = self._session_uid, len(self._estimates), len(done)
        p.estimate_total_s = plan.total_s
        p.estimate_remaining_s = plan.total_s - sum(self._estimates.get(k, 0.0) for k in done)
        self._set_state(State.RUNNING)
        gen = spec.func(plan.params)
        value: Any = None
        final = State.FINISHED
        wall0 = time.perf_counter()
        try:
            step = gen.send(None)
            while True:
                step = gen.send(self._execute(step, done))
        except StopIteration as stop:
            value = stop.value
            self._stop_safely("finished")
        except Exception as exc:  # Aborted, a device or timing fault, or anything unexpected: never skip the stop
            if self._abort_requested:  # an abort or emergency stop; device errors it causes are its consequence
                final = State.ESTOPPED if self._estop else State.ABORTED
                self._record(self.event, "abort", f"{'emergency stop' if self._estop else 'abort'}: {exc}",
                             "critical" if self._estop else "warning")  # fmt: skip
                if not self._estop:
                    self._stop_safely("abort")
            else:
                final = State.FAILED
                expected = isinstance(exc, DeviceError | TimingFault)
                p.faults.append(f"{type(exc).__name__}: {exc}" + ("" if expected else " (unexpected)"))
                if not expected:
                    log.error("run failed on an unexpected error", exc_info=exc)
                self.publish("fault", {"kind": type(exc).__name__, "message": str(exc)})
                self._stop_safely(p.faults[-1])
                self._record(self.event, "fault", p.faults[-1], "error")
        finally:
            with contextlib.suppress(Exception):
                gen.close()
        self.freq_hz = 0.0
        self._record(self.store.set_status, self._session_uid, STORE_STATUS[final])
        self._record(self.event, "wall_time", f"{time.perf_counter() - wall0:.2f} s of wall time")
        self._record(self._set_state, final)
        self.progress.state = final  # even if the store could not take it
        self._publish_progress()
        return self._session_uid, value

    def _record(self, write: Callable[..., Any], *args: Any) -> None:
        """A write of the run's outcome; a store that refuses it (locked, gone) costs the record, not the stop."""
        try:
            write(*args)
        except Exception as exc:
            msg = f"could not record {getattr(write, '__name__', 'it')}{args!r}: {type(exc).__name__}: {exc}"
            log.error("%s", msg)
            self.progress.faults.append(msg)

    def _stop_safely(self, reason: str) -> None:
        """Every moving device to a safe state through the supervisor (bounded: ramp, else quick stop)."""
        state = self.supervisor.safe_state(reason)
        self._record(self.event, "safe_state", state.describe(), "info" if state.how == "safe stop" else "critical")
