"""One station under control: its devices, session store, engine and telemetry.

The controller validates a procedure and its parameters, plans it (dry run
with time estimates) before anything moves, runs it in a worker thread, and
once it finishes runs the procedure's analysis, stores the results and
writes the report. The CLI (`station run`, `station calibrate`, `station
resume`) and the control server behind the web panel (`station serve`) use it
alike.

The controller owns the station's one supervisor of motion (station.engine.supervisor):
it ties the drive's master heartbeat to the supervisor's tick, watches the
engine thread of every run, and if that thread is lost (or does not end within
its grace after an abort) stops every moving device, marks the session failed
and releases whoever waits (`wait()` always returns once the worker is gone).
At start-up, sessions of the store found `running` with no live process are
marked `interrupted` (station.session_lock).
"""

from __future__ import annotations

import functools
import json
import logging
import subprocess
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.config import load_station_config
from station.cli import analysis_job
from station.clock import ClockEvent, host_clock, spawn_party
from station.control_channel import ControlError
from station.defaults import config_dir
from station.engine.context import StationModel
from station.engine.params import ParameterError
from station.engine.planning import Plan, checked_plan, plan_procedure
from station.engine.protocols import StationHardware
from station.engine.registry import Analysis, ProcedureSpec, get_procedure, load_library
from station.engine.runner import Engine, State, StopCount
from station.engine.supervisor import QUICK_STOP_BOUND_S, MotionSupervisor, SafeState
from station.errors import InputError
from station.interchange import write_session
from station.session_lock import INTERRUPTED, recover_interrupted
from station.store import SessionStore

Publisher = Callable[[str, dict], None]


ANALYSIS_TIMEOUT_S = 600.0
RESUMABLE = ("aborted", "failed", INTERRUPTED, "running")  # running: left by a crash and not yet found
log = logging.getLogger(__name__)


@dataclass
class RunOutcome:
    session_uid: str
    state: State
    analysis: Analysis | None
    report_path: Path | None
    faults: list[str]
    result_path: Path | None = None  # the analysis's results as JSON (write_run_files)
    export_path: Path | None = None  # the session as piga-session/1


def not_here(spec: ProcedureSpec, model: StationModel) -> str | None:
    """Why the procedure's dry run with its defaults does not plan on the station of `model`; None if it does (or if
    it has required parameters, so that no dry run can tell without them)."""
    try:
        params = spec.validate({})
    except ParameterError:
        return None
    try:
        plan_procedure(spec, params, model)
    except InputError as exc:
        return str(exc)
    return None


@functools.cache
def station_model_of(path: Path) -> StationModel:
    """What planning knows of the station of a station file."""
    return load_station_config(path).station_model()


def fit(spec: ProcedureSpec, model: StationModel) -> dict:
    """{"not_here": None} for a procedure this station runs; else why not and the shipped station files it plans on."""
    why = not_here(spec, model)
    if why is None:
        return {"not_here": None, "station_files": []}
    files = sorted(config_dir().joinpath("stations").glob("*.toml"))
    return {"not_here": why, "station_files": [f.name for f in files if not_here(spec, station_model_of(f)) is None]}


def write_run_files(store: SessionStore, outcome: RunOutcome, out_dir: Path) -> None:
    """What every run writes beside its report, from the CLI or the panel alike: the analysis's results as
    out_dir/result-UID.json (when there is an analysis) and the session as piga-session/1 in out_dir/session-UID;
    their paths into the outcome."""
    out_dir.mkdir(parents=True, exist_ok=True)
    if outcome.analysis is not None:
        outcome.result_path = out_dir / f"result-{outcome.session_uid}.json"
        outcome.result_path.write_text(json.dumps(outcome.analysis.results, indent=2))
    outcome.export_path = out_dir / f"session-{outcome.session_uid}"
    write_session(store.load_session(outcome.session_uid), outcome.export_path, overwrite=True)


class StationController:
    """Runs one procedure at a time on one station; every method is thread-safe."""

    def __init__(
        self,
        hardware: StationHardware,
        store: SessionStore,
        model: StationModel,
        *,
        reports_dir: str | Path,
        publish: Publisher | None = None,
    ) -> None:
        self.hw = hardware
        self.store = store
        self.model = model
        self.reports_dir = Path(reports_dir)
        self.publish: Publisher = publish or (lambda topic, msg: None)
        self._link = host_clock()  # what the CLI and the panel wait on: the host's wall time
        self.supervisor = MotionSupervisor(hardware, clock=hardware.clock).start()
        self.engine = Engine(hardware, store, publish, self.supervisor)
        self._lock = threading.Lock()
        self._worker: threading.Thread | None = None
        self._outcome: RunOutcome | None = None
        self._started = threading.Event()
        self._worker_ended = self._link.event()
        self.after_run: list[Callable[[RunOutcome], None]] = []  # called in the worker once a run has ended
        self._start_error: BaseException | None = None
        self.interrupted = recover_interrupted(store)
        self._analyst: subprocess.Popen[str] | None = None  # started once a session that needs one is open
        self._analyst_lock = threading.Lock()
        self._library: list[dict] | None = None  # library(), worked out once
        self._library_lock = threading.Lock()
        self.analysing = False  # a finished run's analysis is under way (the panel shows 'analysing')

    def close(self, timeout_s: float = 30.0) -> None:
        """End any run (abort, wait at most timeout_s), then stop supervising: what every exit path calls."""
        if self.busy:
            self.abort()
            self.wait(timeout_s=timeout_s)
        self.supervisor.close()
        self._dismiss_analyst()

    # ---- library and planning ------------------------------------------------------------

    def library(self) -> list[dict]:
        """Every procedure's declaration, and whether this station runs it: `not_here` is None where its dry run with
        the defaults plans on this station, else why not and `station_files`, the shipped station files it plans on
        (worked out once: some 0.3 s of dry runs beside the library's imports)."""
        with self._library_lock:
            if self._library is None:
                self._library = [spec.describe() | fit(spec, self.model) for spec in load_library().values()]
            return self._library

    def plan(self, procedure: str, params: dict[str, Any], checked: bool = False) -> tuple[ProcedureSpec, Plan]:
        """Validate parameters and every step (ProcedureError, ParameterError, ValidationError); nothing moves.
        checked: the operator's dry run, which checks the design first (RefusedDesignError) and carries its warnings."""
        spec = get_procedure(procedure)
        return spec, (checked_plan if checked else plan_procedure)(spec, spec.validate(params), self.model)

    # ---- runs ---------------------------------------------------------------------------------

    @property
    def busy(self) -> bool:
        """A run is under way: its worker lives and has not ended the run (what is left of it then is exiting)."""
        return self._worker is not None and self._worker.is_alive() and not self._worker_ended.is_set()

    def start(
        self,
        procedure: str,
        params: dict[str, Any],
        *,
        instrument_serial: str = "",
        resume_uid: str | None = None,
        stops_seen: StopCount | None = None,
        checked: bool = True,
    ) -> tuple[str, Plan]:
        """Plan (a new session's design checked first: RefusedDesignError before anything moves; `checked=False` runs
        a design identification cannot use, as the engine's own tests do), then start the run in a worker thread;
        (session uid, plan) once the session exists.

        An abort or emergency stop requested after `stops_seen` (the engine's stop_count() when the request was
        received; default: when this call began) is the run's own: it ends the run before its first step, with
        the outcome recorded, however early it came (while planning, while the session was being created)."""
        seen = self.engine.stop_count() if stops_seen is None else stops_seen
        # a new design is checked however it came (a bare `start` on the control channel too); a resumed session
        # was checked when it started
        spec, plan = self.plan(procedure, params, checked=checked and resume_uid is None)
        if resume_uid is None:
            self.engine.provenance(instrument_serial)  # a real station refuses to start without a serial number
        with self._lock:
            if self.busy:
                raise ControlError(f"a procedure is already running (session {self.engine.progress.session_uid})")
            self._outcome = None
            self._start_error = None
            self._started.clear()
            self._worker_ended.clear()
            self._worker = spawn_party(  # the engine acts in station time: the clock waits for it
                self.hw.clock, "engine", lambda: self._run(spec, plan, instrument_serial, resume_uid, seen)
            )
        self._started.wait()
        if self._start_error is not None:  # the session could not be opened (locked, unknown): nothing moved
            raise self._start_error
        return self.engine.progress.session_uid, plan

    def resume_session(self, uid: str, *, stops_seen: StopCount | None = None) -> tuple[str, Plan]:
        """Continue a crashed or aborted session with the procedure and parameters it was started with (stops_seen:
        as in start)."""
        seen = self.engine.stop_count() if stops_seen is None else stops_seen
        cfg = self.store.session_config(uid)
        if "procedure" not in cfg:
            raise ControlError(f"session {uid} was not started by the engine: nothing to resume")
        row = next(s for s in self.store.sessions() if s["uid"] == uid)
        if row["status"] not in RESUMABLE:
            raise ControlError(f"session {uid} is {row['status']}: only {', '.join(RESUMABLE[:3])} ones resume")
        serial = row["instrument_serial"]
        return self.start(cfg["procedure"], cfg["params"], instrument_serial=serial, resume_uid=uid, stops_seen=seen)

    def wait(self, timeout_s: float | None = None) -> RunOutcome | None:
        """The outcome once the run has ended (None while it runs); never None once its worker is gone."""
        worker = self._worker
        if worker is not None:
            deadline_s = None if timeout_s is None else self._link.now_s() + timeout_s
            while worker.is_alive() and self._outcome is None:  # a stuck worker's outcome may come from the supervisor
                left_s = 0.05 if deadline_s is None else min(0.05, deadline_s - self._link.now_s())
                if left_s <= 0:
                    break
                self._worker_ended.wait(timeout_s=left_s)
            if not worker.is_alive() and self._outcome is None:  # lost: the supervisor's on_lost writes the outcome
                bound_s = self.supervisor.bound_s + QUICK_STOP_BOUND_S + 1.0
                self.supervisor.wait_lost(timeout_s=bound_s if timeout_s is None else min(timeout_s, bound_s))
        return self._outcome

    def run(self, procedure: str, params: dict[str, Any], **kw: Any) -> RunOutcome:
        """start() and wait(); the outcome of the run."""
        self.start(procedure, params, **kw)
        outcome = self.wait()
        assert outcome is not None
        return outcome

    def pause(self) -> None:
        self.engine.pause()

    def resume(self) -> None:
        self.engine.resume()

    def abort(self) -> None:
        """Abort at the next event; if the engine does not end within the supervisor's grace, motion is stopped."""
        self.engine.abort()
        self.supervisor.expect_end()

    def emergency_stop(self) -> None:
        self.engine.emergency_stop()
        self.supervisor.expect_end()

    def reset(self) -> None:
        """Clear an emergency stop or a drive fault once its cause is removed (not while a run is under way)."""
        if self.busy:
            raise ControlError("a procedure is running: abort it before a reset")
        self.hw.reset()

    def status(self) -> dict:
        p = self.engine.progress.to_json()
        return p | self.hw.status() | {"busy": self.busy, "freq_hz": self.engine.freq_hz,
                                       "index_deg": self.engine.position_deg, "analysing": self.analysing}  # fmt: skip

    def beacon(self, period_s: float = 0.2) -> ClockEvent:
        """Publish `status` every period_s of link (wall) time (the panel's heartbeat) until the returned event is
        set."""
        stop = self._link.event()

        def loop() -> None:
            while not stop.wait(timeout_s=period_s):
                self.publish("status", self.status())

        threading.Thread(target=loop, name="status-beacon", daemon=True).start()
        return stop

    # ---- worker ---------------------------------------------------------------------------------

    def _on_lost(self, reason: str, safe: SafeState) -> None:
        """The supervisor found the run's engine thread lost: record the outcome, release whoever waits."""
        uid = self.engine.progress.session_uid
        fault = f"supervisor: {reason}; {safe.describe()}"
        self.engine.progress.state = State.FAILED
        self.engine.progress.faults.append(fault)
        self.publish("fault", {"kind": "supervisor", "message": fault})
        try:
            if uid:
                self.store.set_status(uid, "failed")
                self.store.add_event(uid, "fault", fault, "critical")
        except Exception as exc:  # the outcome stays in RunOutcome and the log
            log.error("could not record the lost run of %s: %s", uid, exc)
        if self._outcome is None:
            self._outcome = RunOutcome(uid, State.FAILED, None, None, list(self.engine.progress.faults))

    def _run(self, spec: ProcedureSpec, plan: Plan, serial: str, resume_uid: str | None, seen: StopCount) -> None:
        try:
            self._measure_and_analyse(spec, plan, serial, resume_uid, seen)
        finally:
            self._worker_ended.set()  # wakes wait() at once

    def _measure_and_analyse(
        self, spec: ProcedureSpec, plan: Plan, serial: str, resume_uid: str | None, seen: StopCount
    ) -> None:
        engine = self.engine
        me = threading.current_thread()
        opened = False

        def on_open(_uid: str) -> None:
            nonlocal opened
            opened = True
            self.supervisor.watch(me, self._on_lost)
            if spec.analyse is not None:
                with self._analyst_lock:  # imports the library while the session runs
                    self._analyst = analysis_job.start_analyst()
            self._started.set()

        try:
            uid, _ = engine.run(
                spec, plan, instrument_serial=serial, resume_uid=resume_uid, on_open=on_open, stops_seen=seen
            )
        except BaseException as exc:
            if not opened:  # refused before anything moved: start() raises it
                self._start_error = exc
                return
            raise  # the supervisor sees the thread end unreleased, stops motion and records the outcome
        finally:
            self._started.set()
        self.supervisor.release(me)
        state = engine.progress.state
        analysis = report = None
        faults = list(engine.progress.faults)
        try:
            if state == State.FINISHED and spec.analyse is not None:
                self.analysing = True
                self.publish("status", self.status())
                try:
                    analysis, report = self._analyse(spec, uid)
                except (ValueError, subprocess.TimeoutExpired) as exc:  # the data cannot give what the analysis asks
                    faults.append(f"analysis: {exc}")
                    self.store.add_event(uid, "analysis", f"analysis failed: {exc}", "error")
                    self.publish("fault", {"kind": "analysis", "message": str(exc)})
        except Exception as exc:  # nothing moves any more; whoever waits gets the outcome with this fault
            log.exception("analysis of %s failed", uid)
            faults.append(f"analysis: {type(exc).__name__}: {exc}")
        finally:
            self.analysing = False
            self._dismiss_analyst()  # a run that ended without its analysis leaves none idle
            outcome = RunOutcome(uid, state, analysis, report, faults)
            try:
                write_run_files(self.store, outcome, self.reports_dir)
            except Exception as exc:  # the outcome still reaches whoever waits, with this fault
                log.exception("could not write the result and export of %s", uid)
                faults.append(f"export: {type(exc).__name__}: {exc}")
            for hook in self.after_run:  # `station serve --sync-to`: the session to the central history
                try:
                    hook(outcome)
                except Exception:  # a hook never keeps the outcome from whoever waits
                    log.exception("after-run hook %r failed for %s", hook, uid)
            self._worker_ended.set()  # not busy from here: the next start() need not wait for this thread to exit
            self._outcome = outcome  # last: wait() returns once the hooks are done

    def _dismiss_analyst(self) -> None:
        """Stop an analyst that has no job left (the run ended without an analysis, or the controller closes)."""
        with self._analyst_lock:
            job, self._analyst = self._analyst, None
        if job is not None:
            job.kill()
            job.communicate()

    def _analyse(self, spec: ProcedureSpec, uid: str) -> tuple[Analysis, Path]:
        """The procedure's analysis in a child process (station.cli.analysis_job), results into the store."""
        self.reports_dir.mkdir(parents=True, exist_ok=True)
        report = self.reports_dir / f"report-{uid}.html"
        with self._analyst_lock:
            job, self._analyst = self._analyst or analysis_job.start_analyst(), None
        request = json.dumps([spec.name, str(self.store.path), uid, str(report)]) + "\n"
        try:
            stdout, stderr = job.communicate(request, timeout=ANALYSIS_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            job.kill()
            job.communicate()
            raise
        if job.returncode != 0:
            raise ValueError(stderr.strip().splitlines()[-1] if stderr.strip() else f"exit {job.returncode}")
        doc = json.loads(stdout)
        analysis = Analysis(doc["results"], report.read_text(), doc["summary"])
        for method, result in analysis.results.items():
            self.store.add_result(uid, method, result)
        self.publish("analysis", {"session_uid": uid, "summary": analysis.summary, "results": analysis.results})
        return analysis, report
