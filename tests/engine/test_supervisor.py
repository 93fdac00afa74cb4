"""The one supervisor of motion, through the real drivers and emulators: whatever ends a run, the table comes
to rest, the head is held, the outcome is recorded and whoever waits is released; the master heartbeat lives
only as long as the supervisor ticks, and the drive, configured by the driver (0x6007, 0x605A), stops on its own.

Bounds, derived (wall time):
- a safe stop: hw.safe_stop_bound_s() = ramp from 10 Hz at 2 Hz/s (5 station s, 5 ms at 1000x) + 3 SDO
  timeouts + 2 state transitions + the counter abort; a quick stop after it at most QUICK_STOP_BOUND_S;
  the supervisor notices a lost thread within one tick (TICK_S). So the table is at rest within
  bound + QUICK_STOP_BOUND_S + TICK_S of the loss, plus 1 s of slack on a loaded machine.
- a hung supervisor: alive() falls after STALE_S; the heartbeat producer sends every period HB_S, so the
  last heartbeat is at most STALE_S + HB_S before; the drive's consumer trips 3 HB_S later; the crank brakes
  on 0x6085 (10 rev/s^2) from 10 Hz in 1 station s (1 ms at 1000x). Bound: STALE_S + 4 HB_S + 0.5 s slack.
"""

from __future__ import annotations

import dataclasses
import math
import sqlite3
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import pytest

from drivers.errors import DeviceFault, DriverError
from drivers.servo.driver import ABORT_CONNECTION_OPTION, QUICK_STOP_OPTION, ServoLimits, VibrationTableServo
from drivers.servo.emulator import EMCY_HEARTBEAT_ERROR, ServoEmulator
from station.cli.controller import StationController
from station.clock import WallClock
from station.engine import registry
from station.engine.registry import procedure
from station.engine.runner import State
from station.engine.steps import Step
from station.engine.supervisor import QUICK_STOP_BOUND_S, STALE_S, TICK_S
from station.session_lock import SessionLock, SessionLocked, recover_interrupted

from .conftest import CONFIG, PROCEDURE, QUICK

pytestmark = pytest.mark.timeout(120)
HB_S = CONFIG.servo.heartbeat_ms / 1000
PAIR_HB_S = 0.5  # a drive and its driver alone in wall time on a shared machine: host stalls of 0.6-0.7 s are seen


def wait_until(predicate, timeout_s: float) -> float:
    t0 = time.monotonic()
    while not predicate():
        assert time.monotonic() - t0 < timeout_s, f"condition not met within {timeout_s:.2f} s"
        time.sleep(0.005)
    return time.monotonic() - t0


def crank_hz(sim) -> float:
    return sim.world.crank.speed_radps(sim.world.clock.now_s()) / (2 * math.pi)


class LostEngine(BaseException):
    """What kills a thread outright (SystemExit, a C extension's error): no `except Exception` catches it."""


def test_a_lost_engine_thread_stops_motion_records_failed_and_releases_the_caller(make_rig, tmp_path) -> None:
    rig = make_rig()
    killed = threading.Event()

    def publish(topic: str, msg: dict) -> None:  # a telemetry callback that kills the engine thread at point 3
        rig.messages.append((topic, msg))
        if topic == "point" and msg["sequence"] == 2 and threading.current_thread().name == "engine":
            killed.set()
            raise LostEngine("engine thread lost")

    controller = StationController(rig.sim.devices, rig.store, CONFIG.station_model(), reports_dir=tmp_path,
                                   publish=publish)  # fmt: skip
    bound_s = controller.supervisor.bound_s + QUICK_STOP_BOUND_S + TICK_S + 1.0
    try:
        uid, _ = controller.start(PROCEDURE, QUICK)
        assert killed.wait(30), "the run never reached its third point"
        t0 = time.monotonic()
        outcome = controller.wait(bound_s)
        took_s = time.monotonic() - t0
        assert outcome is not None, f"not released within {bound_s:.1f} s: {controller.supervisor.last}"
        assert took_s < bound_s
        assert outcome.state == State.FAILED and any("supervisor" in f for f in outcome.faults)
        assert crank_hz(rig.sim) == 0.0
        assert rig.sim.emulators["servo"].state in ("SWITCH ON DISABLED", "QUICK STOP ACTIVE")
        assert rig.sim.devices.head.held  # stopped and held until a reset
        row = next(s for s in rig.store.sessions() if s["uid"] == uid)
        assert row["status"] == "failed" and row["n_points"] == 3  # every finished point kept
        events = [e["message"] for e in rig.store.events(uid) if e["kind"] == "fault"]
        assert any("safe state by" in m for m in events)
        # resumable: a reset releases the head, the rest of the session is measured, none twice
        controller.reset()
        controller.resume_session(uid)
        done = controller.wait(60)
        assert done is not None and done.state == State.FINISHED
        assert [p.sequence for p in rig.store.load_session(uid).points] == list(range(10))
    finally:
        controller.close()


def test_an_unexpected_store_error_fails_the_run_with_the_devices_safe(make_rig) -> None:
    """A locked store raises sqlite3.OperationalError in add_point: once this skipped the safe stop."""
    rig = make_rig()
    rig.store._db.execute("PRAGMA busy_timeout = 300")  # the test's store gives up after 0.3 s, not 30 s
    blocker = sqlite3.connect(rig.store.path, timeout=5, isolation_level=None, check_same_thread=False)
    locked = threading.Event()

    def lock_at_second_point() -> None:
        wait_until(lambda: sum(t == "point" for t, _ in rig.messages) >= 2, 30)
        blocker.execute("BEGIN EXCLUSIVE")
        locked.set()
        wait_until(lambda: any(t == "fault" for t, _ in rig.messages), 30)
        blocker.execute("ROLLBACK")

    helper = threading.Thread(target=lock_at_second_point, daemon=True)
    helper.start()
    uid, _ = rig.controller.start(PROCEDURE, QUICK)
    outcome = rig.controller.wait(60)
    helper.join(10)
    blocker.close()
    assert locked.is_set()
    assert outcome is not None and outcome.state == State.FAILED
    assert any("OperationalError" in f for f in outcome.faults)
    assert crank_hz(rig.sim) == 0.0 and rig.sim.emulators["servo"].state == "SWITCH ON DISABLED"
    points = rig.store.load_session(uid).points
    assert len(points) >= 2 and [p.sequence for p in points] == list(range(len(points)))
    status = next(s["status"] for s in rig.store.sessions() if s["uid"] == uid)
    assert status in ("failed", "running")  # failed, unless the store was still locked when it was written
    if status == "running":  # then the next start-up finds it without a live process
        assert recover_interrupted(rig.store) == [uid]


def test_the_drive_is_configured_to_stop_on_its_own_and_the_driver_reads_it_back(make_rig) -> None:
    rig = make_rig()
    servo = rig.sim.devices.servo
    assert servo.master_loss_options() == {"0x6007": ABORT_CONNECTION_OPTION, "0x605A": QUICK_STOP_OPTION}
    assert rig.sim.emulators["servo"].master_loss_options == (ABORT_CONNECTION_OPTION, QUICK_STOP_OPTION)


def _servo_pair(clock=None):
    clock = clock or WallClock()
    cfg = dataclasses.replace(CONFIG.servo, channel=f"sup-test-{uuid.uuid4().hex[:8]}", timeout_s=0.2,
                              heartbeat_ms=round(PAIR_HB_S * 1000), tpdo_event_timer_ms=10)  # fmt: skip
    emu = ServoEmulator.from_config(cfg, clock)
    emu.start()
    return emu, VibrationTableServo(cfg, ServoLimits.from_config(CONFIG), clock), clock


def test_a_drive_that_does_not_keep_the_master_loss_options_is_refused() -> None:
    emu, servo, _ = _servo_pair()
    try:
        emu.ignore_option_writes()
        with pytest.raises(DeviceFault, match="0x6007"):
            servo.open()
    finally:
        servo.close()
        emu.stop()


def test_without_the_options_a_lost_master_leaves_the_crank_turning() -> None:
    """Why the driver writes 0x6007: the EDS default (0, no action) keeps the crank at speed."""
    emu, servo, clock = _servo_pair()
    try:
        servo.open()
        servo._sdo_write(0x6007, 0)  # undo the driver's setting, as an unconfigured drive would be
        servo.enable()
        servo.set_frequency(1.5)
        servo.master_alive = lambda: False  # the master falls silent
        time.sleep(4 * PAIR_HB_S + 0.3)
        assert emu.state == "OPERATION ENABLED"
        assert emu.crank.speed_radps(clock.now_s()) / (2 * math.pi) == pytest.approx(1.5, abs=1e-6)
        servo.master_alive = lambda: True
    finally:
        servo.close()
        emu.stop()


def test_a_hung_supervisor_silences_the_heartbeat_and_the_drive_stops_the_crank(make_rig) -> None:
    rig = make_rig()
    devices = rig.sim.devices
    devices.set_vibration(8.0)
    assert crank_hz(rig.sim) == pytest.approx(8.0, abs=1e-3)
    rig.controller.supervisor.freeze()
    t0 = time.monotonic()
    took_s = wait_until(lambda: crank_hz(rig.sim) == 0.0, STALE_S + 4 * HB_S + 0.5)
    assert took_s > STALE_S  # the heartbeat did go out while the supervisor still ticked
    assert rig.sim.emulators["servo"].state == "FAULT"
    with pytest.raises(DeviceFault, match=f"0x{EMCY_HEARTBEAT_ERROR:04X}"):
        devices.servo.watch(1.0)
    assert time.monotonic() - t0 < STALE_S + 4 * HB_S + 1.5


def test_one_process_per_session_and_interrupted_sessions_are_found(make_rig, tmp_path) -> None:
    rig = make_rig()
    short = QUICK | {"positions_deg": [0, 180]}  # short windows: 90 deg counts slowly (too few points to identify)
    out = rig.controller.run(PROCEDURE, short, checked=False)
    uid = out.session_uid
    rig.store.set_status(uid, "running")  # as a crash would leave it
    held = SessionLock(rig.store.path, uid)  # another process (or run) holds the session
    try:
        with pytest.raises(SessionLocked, match=f"session {uid} is being run by another process"):
            rig.controller.resume_session(uid)
        assert not rig.controller.busy
        assert recover_interrupted(rig.store) == []  # its holder is alive
    finally:
        held.release()
    assert recover_interrupted(rig.store) == [uid]  # no live process any more
    assert next(s["status"] for s in rig.store.sessions() if s["uid"] == uid) == "interrupted"
    assert any(e["kind"] == "interrupted" for e in rig.store.events(uid))
    # an interrupted session resumes like an aborted one (here nothing is left to measure)
    rig.controller.resume_session(uid)
    assert rig.controller.wait(30).state == State.FINISHED


def test_store_path_locks_live_next_to_the_store(tmp_path: Path) -> None:
    with SessionLock(tmp_path / "s.sqlite", "X") as lock:
        assert lock.path == tmp_path / "s.sqlite.locks" / "X.lock"
        assert oct(lock.path.stat().st_mode & 0o777) == "0o600"


@dataclass(frozen=True)
class UncooperativeStep(Step):
    """A lab's own step that sets the table going, then blocks in a call that never looks at an abort."""

    freq_hz: float
    block_s: float

    def plan(self, ctx) -> tuple[float, None]:
        return self.block_s, None

    def run(self, ctx) -> None:
        ctx.set_table(self.freq_hz)
        time.sleep(self.block_s)  # wall time: a driver call that hangs, from the engine's point of view


def _uncooperative(params: dict):
    yield UncooperativeStep(8.0, 6.0)


def test_an_engine_that_ignores_an_abort_is_stopped_by_the_supervisor_within_its_grace(make_rig, monkeypatch) -> None:
    # registered for this test only: the library other tests on this worker see is the shipped one
    monkeypatch.setattr(registry, "_REGISTRY", registry.load_library())  # a copy, the shipped procedures loaded
    procedure("test.uncooperative", "a step that ignores aborts", [])(_uncooperative)
    rig = make_rig()
    controller = rig.controller
    controller.supervisor.abort_grace_s = 1.0  # the same rule as ABORT_GRACE_S, at a test's scale
    controller.start("test.uncooperative", {})
    wait_until(lambda: crank_hz(rig.sim) == pytest.approx(8.0, abs=1e-3), 20)
    t0 = time.monotonic()
    controller.abort()
    outcome = controller.wait(1.0 + QUICK_STOP_BOUND_S + TICK_S + 2.0)
    took_s = time.monotonic() - t0
    assert outcome is not None and outcome.state == State.FAILED, outcome
    assert any("did not end within 1 s of an abort" in f for f in outcome.faults)
    assert 1.0 <= took_s < 1.0 + QUICK_STOP_BOUND_S + TICK_S + 2.0
    assert crank_hz(rig.sim) == 0.0 and rig.sim.devices.head.held  # quick-stopped and held by the supervisor


def test_after_a_bus_off_a_failed_reset_then_a_run_fail_with_typed_errors_not_a_dead_thread(make_rig) -> None:
    """Once a KeyError in the engine thread: the drive's link gone for good, reset cannot reopen it."""
    rig = make_rig()
    rig.sim.emulators["servo"].go_bus_off()  # permanent: the drive never answers again
    with pytest.raises(DriverError):  # DeviceTimeout: no SDO answer to the reopen (typed, not a KeyError)
        wait_until(lambda: rig.sim.devices.status()["drive_fault"] is not None, 5)
        rig.controller.reset()
    assert rig.sim.devices.servo.state == "UNKNOWN"
    rig.controller.start(PROCEDURE, QUICK)
    outcome = rig.controller.wait(30)
    assert outcome is not None and outcome.state == State.FAILED
    # typed: the head refuses to move while the crank's state is unknown, or the drive's link is named gone
    typed = ("InterlockError: indexing head", "Disconnected: vibration table servo", "DeviceTimeout")
    assert outcome.faults and outcome.faults[0].startswith(typed), outcome.faults
    assert not any("KeyError" in f or "unexpected" in f for f in outcome.faults)
    assert crank_hz(rig.sim) == 0.0
