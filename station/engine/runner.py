"""The run engine: one procedure at a time through the station's drivers, every point stored durably.

State machine: idle -> running <-> pausing -> paused -> running ... ->
finished | aborted | estopped | failed. Pause takes effect at safe points
(before a point starts, and at Checkpoint steps); abort stops at the next
event of the open window (the counter is aborted, the table ramps down);
emergency stop acts at once from the calling thread (quick stop of the
table, the head held). Each finished point is committed to the store before
the next step starts, so a fault or a kill loses no finished measurement;
`run(..., resume_uid=...)` skips the points a session already holds.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from typing import Any

from drivers.counter_timer import Event
from drivers.errors import DriverError
from station.engine.hardware import StationHardware
from station.engine.planning import Plan
from station.engine.registry import ProcedureSpec
from station.engine.steps import (
    CaptureGrating,
    Checkpoint,
    MeasureFrequency,
    MeasurePoint,
    MoveIndex,
    Note,
    SetVibration,
    Step,
)
from station.engine.timing import TimingFault, capture_timing, cross_check
from station.session import PointRecord, RawStreams
from station.store import SessionStore


class State(StrEnum):
    IDLE = "idle"
    RUNNING = "running"
    PAUSING = "pausing"
    PAUSED = "paused"
    ABORTING = "aborting"
    FINISHED = "finished"
    ABORTED = "aborted"
    ESTOPPED = "estopped"
    FAILED = "failed"


class Aborted(Exception):  # noqa: N818 - a control-flow signal, not an error
    """Raised inside the engine thread when an abort or emergency stop was requested."""


@dataclass
class Progress:
    state: State = State.IDLE
    session_uid: str = ""
    procedure: str = ""
    point_id: str = ""
    points_done: int = 0
    points_total: int = 0
    estimate_total_s: float = 0.0
    estimate_remaining_s: float = 0.0
    elapsed_s: float = 0.0
    message: str = ""
    faults: list[str] = field(default_factory=list)

    @property
    def fraction(self) -> float:
        if self.estimate_total_s <= 0:
            return 0.0
        return min(1.0, 1.0 - self.estimate_remaining_s / self.estimate_total_s)


Publisher = Callable[[str, dict], None]


class Engine:
    """Runs procedures on a station; control calls are thread-safe."""

    GRATING_CHECK_S = 0.4  # grating stretch recorded at the start of each vibration window

    def __init__(self, hardware: StationHardware, store: SessionStore, publish: Publisher | None = None) -> None:
        self.hw = hardware
        self.store = store
        self.publish = publish or (lambda topic, msg: None)
        self.progress = Progress()
        self._lock = threading.Lock()
        self._resume = threading.Event()
        self._resume.set()
        self._pause_requested = False
        self._abort_requested = False
        self._estop = False
        self._position_deg: float | None = None
        self._freq_hz = 0.0
        self._t0_s = 0.0
        self._session_uid = ""

    # --- control, from any thread ------------------------------------------------------------
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
            self._abort_requested = True
            if self.progress.state in (State.RUNNING, State.PAUSING, State.PAUSED):
                self._set_state(State.ABORTING)
            self._resume.set()

    def emergency_stop(self) -> None:
        """Quick-stop the table and hold the head now, then stop the procedure."""
        self.hw.emergency_stop()
        with self._lock:
            self._estop = True
            self._abort_requested = True
            self._resume.set()
        self.publish("fault", {"kind": "estop", "message": "emergency stop"})

    # --- internals ---------------------------------------------------------------------------------
    def _set_state(self, state: State) -> None:
        self.progress.state = state
        self.publish("state", {"state": str(state), "session_uid": self.progress.session_uid})
        if self._session_uid:
            self.store.add_event(self._session_uid, "state", str(state))

    def _check_abort(self) -> None:
        if self._abort_requested:
            raise Aborted("emergency stop" if self._estop else "abort requested")

    def _safe_point(self) -> None:
        self._check_abort()
        with self._lock:
            if self._pause_requested:
                self._pause_requested = False
                self._resume.clear()
                self._set_state(State.PAUSED)
        self._resume.wait()
        self._check_abort()

    def _event(self, kind: str, message: str, level: str = "info") -> None:
        self.store.add_event(self._session_uid, kind, message, level)
        self.publish("event", {"kind": kind, "message": message, "level": level})

    def _publish_progress(self) -> None:
        p = self.progress
        p.elapsed_s = self.hw.clock.now_s() - self._t0_s
        self.publish("progress", {k: v for k, v in asdict(p).items() if k != "faults"} | {"fraction": p.fraction})

    # --- steps -----------------------------------------------------------------------------------------
    def _set_freq(self, freq_hz: float, settle_s: float) -> float:
        measured = freq_hz
        if freq_hz != self._freq_hz:
            measured = self.hw.set_vibration(freq_hz)
            self._freq_hz = freq_hz
            self.publish("motion", {"freq_hz": measured, "commanded_hz": freq_hz})
        self.hw.clock.sleep_s(settle_s)
        return measured

    def _move(self, position_deg: float) -> None:
        if self._position_deg is not None and abs(position_deg - self._position_deg) < 1e-9:
            return
        if self._freq_hz != 0:
            self._set_freq(0.0, 0.0)  # the head must not move while the table vibrates
        self._position_deg = self.hw.move_index(position_deg)
        self.publish("motion", {"index_deg": self._position_deg})

    def _measure(self, step: MeasurePoint, sequence: int) -> tuple[PointRecord, RawStreams | None]:
        self._move(step.position_deg)
        self._set_freq(step.freq_hz, step.settle_s)
        self._check_abort()
        window_started = self.hw.clock.now_s()
        expected = self._plan_window_s.get(step.point_id, 560.0)

        def on_event(ev: Event) -> None:
            self._check_abort()
            if ev.kind in ("open", "close", "heartbeat"):
                elapsed = max(ev.t_s - window_started, 0.0)
                self.publish(
                    "window",
                    {
                        "point_id": step.point_id,
                        "event": ev.kind,
                        "elapsed_s": elapsed,
                        "expected_s": expected,
                        "fraction": min(elapsed / expected, 1.0),
                    },
                )

        grating_s = self.GRATING_CHECK_S if step.freq_hz else 0.0
        try:
            result, (g_t, g_z) = self.hw.measure_window(
                step.preset_pulses, stream_edges=step.raw, on_event=on_event, grating_s=grating_s
            )
        except Aborted:
            self.hw.abort_window()
            raise
        timing = capture_timing(result.open_s, result.close_s, result.crossings_s, step.freq_hz)
        extra = {}
        if step.freq_hz:
            check = cross_check(result.crossings_s, g_t, g_z, step.freq_hz)
            extra = {k: f"{v:.9g}" for k, v in check.items()}
        record = PointRecord(
            step.point_id, sequence, result.open_s - self._t0_s, step.position_deg, step.freq_hz,
            "vibration" if step.freq_hz else "static", result.pulses, timing.Tm_s, timing.t1_s, timing.t2_s,
            timing.Np, extra,
        )  # fmt: skip
        raw = None
        if step.raw:
            raw = RawStreams(g_t - result.open_s, g_z, result.edges_t_s - result.open_s, result.edges_dir,
                             result.crossings_s - result.open_s)  # fmt: skip
        return record, raw

    def _execute(self, step: Step, sequence: int, done: dict[str, PointRecord]) -> Any:
        if isinstance(step, MeasurePoint):
            self._safe_point()
            if step.point_id in done:
                return done[step.point_id]
            self.progress.point_id = step.point_id
            self._publish_progress()
            record, raw = self._measure(step, sequence)
            self.store.add_point(self._session_uid, record, raw)  # durable before anything else happens
            done[step.point_id] = record
            self.progress.points_done += 1
            self.progress.estimate_remaining_s -= self._plan_point_s.get(step.point_id, 0.0)
            self.publish("point", asdict(record))
            self._publish_progress()
            return record
        if isinstance(step, MoveIndex):
            self._move(step.position_deg)
            return self._position_deg
        if isinstance(step, SetVibration):
            return self._set_freq(step.freq_hz, step.settle_s)
        if isinstance(step, CaptureGrating):
            return self.hw.capture_grating(step.duration_s)
        if isinstance(step, MeasureFrequency):
            return self.hw.measure_frequency(step.periods)
        if isinstance(step, Checkpoint):
            self._safe_point()
            self._publish_progress()
            return None
        if isinstance(step, Note):
            self._event("note", step.message)
            return None
        raise TypeError(f"unknown step {step!r}")

    # --- run ----------------------------------------------------------------------------------------------
    def run(
        self,
        spec: ProcedureSpec,
        params: dict[str, Any],
        plan: Plan,
        *,
        instrument_serial: str = "",
        resume_uid: str | None = None,
        config: dict | None = None,
    ) -> tuple[str, Any]:
        """Run a validated procedure; returns (session uid, the procedure's return value)."""
        done: dict[str, PointRecord] = {}
        if resume_uid:
            self._session_uid = resume_uid
            done = {p.point_id: p for p in self.store.load_session(resume_uid, with_raw=False).points}
            self.store.set_status(resume_uid, "running")
            self._event("resume", f"resuming with {len(done)} points already stored")
        else:
            cfg = {"procedure": spec.name, "params": params} | (config or {})
            self._session_uid = self.store.create_session(
                self.hw.station, spec.name, instrument_serial=instrument_serial, config=cfg
            )
        self._plan_point_s = plan.point_estimates()
        self._plan_window_s = {s.step.point_id: s.estimate_s for s in plan.steps if isinstance(s.step, MeasurePoint)}
        self._t0_s = self.hw.clock.now_s() - (max((p.start_s + p.Tm_s for p in done.values()), default=0.0))
        self.progress = Progress(
            session_uid=self._session_uid, procedure=spec.name, points_total=len(plan.points),
            points_done=len(done), estimate_total_s=plan.total_s,
            estimate_remaining_s=plan.total_s - sum(self._plan_point_s.get(p, 0.0) for p in done),
        )  # fmt: skip
        self._abort_requested = self._estop = self._pause_requested = False
        self._set_state(State.RUNNING)
        gen = spec.func(params)
        sequence = len(done)
        value: Any = None
        wall0 = time.perf_counter()
        try:
            step = gen.send(None)
            while True:
                is_new_point = isinstance(step, MeasurePoint) and step.point_id not in done
                result = self._execute(step, sequence, done)
                if is_new_point:
                    sequence += 1
                step = gen.send(result)
        except StopIteration as stop:
            value = stop.value
            self.hw.safe_stop()
            self._freq_hz = 0.0
            self.store.set_status(self._session_uid, "finished")
            self._set_state(State.FINISHED)
        except Aborted as exc:
            if not self._estop:
                self.hw.safe_stop()
            self._freq_hz = 0.0
            self.store.set_status(self._session_uid, "aborted")
            self._event("abort", str(exc), "critical" if self._estop else "warning")
            self._set_state(State.ESTOPPED if self._estop else State.ABORTED)
        except (DriverError, TimingFault) as exc:
            self.progress.faults.append(str(exc))
            self._event("fault", f"{type(exc).__name__}: {exc}", "error")
            self.publish("fault", {"kind": type(exc).__name__, "message": str(exc)})
            try:
                self.hw.safe_stop()
            except DriverError as stop_exc:
                self._event("fault", f"safe stop failed: {stop_exc}", "critical")
                self.hw.emergency_stop()
            self._freq_hz = 0.0
            self.store.set_status(self._session_uid, "failed")
            self._set_state(State.FAILED)
        finally:
            gen.close()
        self._event("wall_time", f"{time.perf_counter() - wall0:.2f} s of wall time")
        return self._session_uid, value
