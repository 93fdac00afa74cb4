"""Fault campaign: every emulator fault, injected during a window and between windows, through the real drivers,
emulators, engine, supervisor and store (the deterministic simulated station paced at SPEED x real time, so that a
fault injected from the engine's thread meets a station whose time flows; a 4-point session).

For each case: the typed error (or the point repeated) within the case's stated bound; the devices safe at the end
(crank at rest, drive not enabled, head still); every finished point kept (stored points = announced points,
sequences 0..n-1 without a gap or a repeat); the outcome recorded: `finished` after a transient fault (the point
repeated, station.engine.runner's policy) or `failed` and resumable after any other.

Stated bounds, in station seconds from the injection (the discrete-event station's time, which a busy host does
not stretch; wall times are in the benchmark's table): the typed error or the repeat comes at the faulty
device's next use, at the latest in the point after the one under way (a grating fault shows at the next point's
grating record, a silent drive at the next command or board event, a locked store when the next point is
stored): two of the plan's longest points plus one serial or SDO timeout (DETECT_BOUND_S). A safe state (crank at
rest, drive disabled or faulted) follows within the supervisor's bound (hw.safe_stop_bound_s() +
QUICK_STOP_BOUND_S) of the error, in the clock's link seconds, which here are station seconds.
`python bench/bench_fault_campaign.py` prints the
table in BENCHMARKS.md.
"""

from __future__ import annotations

import math
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from drivers.config import load_station_config
from drivers.pty_link import Fault
from drivers.station import SimulatedStation, simulated_station
from station.cli.controller import StationController
from station.engine.planning import plan_procedure
from station.engine.registry import get_procedure
from station.engine.runner import State
from station.engine.supervisor import QUICK_STOP_BOUND_S
from station.store import SessionStore
from station.twin.config import default_twin

CONFIG = load_station_config(Path(__file__).parents[1] / "config" / "stations/vibration-sim.toml")
PROCEDURE = "integral_precession"
PARAMS = {"positions_deg": [0, 180], "freqs_hz": [10], "window_s": 30, "settle_s": 2}  # 4 points, all short
N_POINTS = 4
SPEED = 200.0
PLAN = plan_procedure(get_procedure(PROCEDURE), get_procedure(PROCEDURE).validate(PARAMS), CONFIG.station_model())
DETECT_BOUND_S = 2 * max(PLAN.key_estimates_s().values()) + CONFIG.servo.timeout_s  # 123 s (points of 41-61 s)
BUSY_TIMEOUT_S = 0.5
PHASES = ("window", "between")


@dataclass
class Run:
    sim: SimulatedStation
    store: SessionStore
    controller: StationController
    messages: list[tuple[float, float, str, dict]] = field(default_factory=list)  # (wall s, station s, topic, msg)
    injected_at: float | None = None
    injected_station_s: float = math.nan
    blocker: sqlite3.Connection | None = None

    def crank_hz(self) -> float:
        return self.sim.world.crank.speed_radps(self.sim.world.clock.now_s()) / (2 * math.pi)


def _lock_store(run: Run) -> None:
    run.blocker = sqlite3.connect(run.store.path, timeout=5, isolation_level=None, check_same_thread=False)
    run.blocker.execute("BEGIN EXCLUSIVE")


@dataclass(frozen=True)
class Case:
    name: str
    inject: Callable[[Run], None]
    policy: str  # "repeat": the point is measured again and the session finishes; "end": it fails, resumable
    error: tuple[str, ...]  # the typed errors the run's first fault may name


def _servo(r: Run):
    return r.sim.emulators["servo"]


def _counter(r: Run):
    return r.sim.emulators["counter"]


def _grating(r: Run):
    return r.sim.emulators["grating"]


CASES = (
    Case("drive fault", lambda r: _servo(r).inject_fault(0x2310), "end", ("DeviceFault",)),
    Case("bus-off", lambda r: _servo(r).go_bus_off(), "end", ("BusOff", "DeviceTimeout")),
    Case("heartbeat loss", lambda r: _servo(r).silence_heartbeat(), "end", ("DeviceTimeout",)),
    Case("SDO silence", lambda r: _servo(r).silence_sdo(), "end", ("DeviceTimeout",)),
    Case("serial disconnect", lambda r: _counter(r).disconnect(), "end", ("Disconnected",)),
    # a garbled frame is a FrameError, or, if it was the ARM's reply and unrecognisable, a ReplyLost
    Case("garbled frame", lambda r: _counter(r).inject(Fault.GARBLE), "repeat", ("FrameError", "ReplyLost")),
    Case("CRC error", lambda r: _counter(r).inject(Fault.CRC_ERROR), "repeat", ("ChecksumError", "ReplyLost")),
    Case("signal loss", lambda r: _grating(r).inject(Fault.SIGNAL_LOSS, None), "end", ("DeviceFault",)),
    Case("counter overflow", lambda r: _counter(r).inject(Fault.COUNTER_OVERFLOW), "end", ("DeviceFault",)),
    Case("store locked", _lock_store, "end", ("OperationalError",)),
)


@dataclass
class Result:
    case: str
    phase: str
    state: str
    detect_s: float
    detect_station_s: float  # the same in station seconds: what the bounds hold, however busy the host
    safe_s: float | None  # injection to crank at rest and drive not enabled (wall s); None: the session went on
    safe_station_s: float | None  # the same in station seconds (what a real station, at 1x, would take)
    points: int
    fault: str


def run_case(case: Case, phase: str, tmp: Path) -> Result:
    """One session with one fault injected at the second window's opening, or after the second point."""
    sim = simulated_station(CONFIG, default_twin(), seed=3, speed=SPEED)
    store = SessionStore(tmp / f"{case.name.replace(' ', '_')}-{phase}.sqlite")
    store._db.execute(f"PRAGMA busy_timeout = {round(BUSY_TIMEOUT_S * 1000)}")  # production waits 30 s
    injected = threading.Event()
    run: Run | None = None

    def publish(topic: str, msg: dict) -> None:
        run.messages.append((time.monotonic(), sim.world.clock.now_s(), topic, msg))
        opened = topic == "window" and msg.get("event") == "open"
        windows = sum(t == "window" and m.get("event") == "open" for _, _, t, m in run.messages)
        trigger = (phase == "window" and opened and windows == 2) or (
            phase == "between" and topic == "point" and msg["sequence"] == 1
        )
        if trigger and not injected.is_set():
            run.injected_at = time.monotonic()
            run.injected_station_s = sim.world.clock.now_s()
            case.inject(run)  # in the engine's own thread: the fault is in place before the window goes on
            injected.set()
        if topic == "fault" and run.blocker is not None:  # the store's refusal is seen: the lock is let go
            run.blocker.execute("ROLLBACK")
            run.blocker.close()
            run.blocker = None

    controller = StationController(sim.devices, store, CONFIG.station_model(), reports_dir=tmp, publish=publish)
    run = Run(sim, store, controller)
    try:
        controller.start(PROCEDURE, PARAMS, checked=False)  # 4 points: an engine run identification cannot use
        assert injected.wait(60), f"{case.name}/{phase}: the fault was never injected"
        safe_at = safe_station_s = None
        while (outcome := controller.wait(0.005)) is None:
            if safe_at is None and run.crank_hz() == 0.0 and sim.emulators["servo"].state != "OPERATION ENABLED":
                safe_at, safe_station_s = time.monotonic(), sim.world.clock.now_s()
        if safe_at is None and outcome.state != State.FINISHED:
            safe_at, safe_station_s = time.monotonic(), sim.world.clock.now_s()
        faults = [(t, t_s, f"{m['kind']}: {m['message']}") for t, t_s, topic, m in run.messages
                  if topic == "fault" and t >= run.injected_at]  # fmt: skip
        assert faults, f"{case.name}/{phase}: no fault reported"
        points = store.load_session(outcome.session_uid).points
        announced = sum(topic == "point" for _, _, topic, _ in run.messages)
        # every finished point kept, none twice
        assert len(points) == announced and [p.sequence for p in points] == list(range(len(points)))
        status = next(s["status"] for s in store.sessions() if s["uid"] == outcome.session_uid)
        # devices safe at the end
        assert run.crank_hz() == 0.0 and sim.emulators["servo"].state != "OPERATION ENABLED"
        assert not sim.world.index_busy(sim.world.clock.now_s())
        went_on = case.policy == "repeat"
        return Result(case.name, phase, f"{outcome.state}/{status}", faults[0][0] - run.injected_at,
                      faults[0][1] - run.injected_station_s, None if went_on else safe_at - run.injected_at,
                      None if went_on else safe_station_s - run.injected_station_s, len(points),
                      faults[0][2])  # fmt: skip
    finally:
        if controller.busy:
            controller.abort()
            controller.wait(30)
        controller.close()
        sim.close()
        store.close()


@pytest.mark.timeout(240)
@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_fault(case: Case, phase: str, tmp_path: Path) -> None:
    r = run_case(case, phase, tmp_path)
    assert any(e in r.fault for e in case.error), r
    assert r.detect_station_s < DETECT_BOUND_S, r
    if case.policy == "repeat":
        assert r.state == "finished/finished" and r.points == N_POINTS, r
        assert "measuring it again" in r.fault
    else:
        assert r.state == "failed/failed" and r.points < N_POINTS, r
        ramp_s = CONFIG.limits.freq_max_hz / CONFIG.limits.ramp_max_hz_per_s
        bound_s = DETECT_BOUND_S + ramp_s + 3 * CONFIG.servo.timeout_s + 3.0 + QUICK_STOP_BOUND_S
        assert r.safe_station_s is not None and r.safe_station_s < bound_s, r
