"""Runs through the real drivers and emulators: finished, paused, aborted, stopped, faulted and resumed
sessions; no finished point is ever lost or measured twice."""

from __future__ import annotations

import math
import time

import pytest

from drivers.pty_link import Fault
from drivers.servo.emulator import ServoEmulator
from station.engine.design_checks import RefusedDesignError
from station.engine.runner import State
from station.twin.config import default_twin

from .conftest import CONFIG, PROCEDURE, QUICK

pytestmark = pytest.mark.timeout(120)


def wait_until(predicate, timeout_s: float) -> None:
    t0 = time.monotonic()
    while not predicate():
        assert time.monotonic() - t0 < timeout_s, "condition not met in time"
        time.sleep(0.01)


def crank_hz(rig) -> float:
    return rig.sim.world.crank.speed_radps(rig.sim.world.clock.now_s()) / (2 * math.pi)


def test_a_session_runs_to_the_end_and_reports(make_rig) -> None:
    rig = make_rig()
    out = rig.controller.run(PROCEDURE, QUICK)
    assert out.state == State.FINISHED and out.faults == []
    session = rig.store.load_session(out.session_uid)
    assert [p.sequence for p in session.points] == list(range(10))
    assert rig.store.sessions()[0]["status"] == "finished"
    # Timing capture of every vibration point: t2 = t1 + Np T - Tm to the 50 ns tick (perfect frequency).
    for p in session.select("vibration"):
        assert p.t1_s + p.Np / p.freq_hz - p.Tm_s - p.t2_s == pytest.approx(0.0, abs=2 * 50e-9)
        assert 0 <= p.t2_s < 1 / p.freq_hz
    # The dry run's window estimates hold. Its nominal rate k0 + kz cos(theta) leaves out kzz, ky, k3 and the
    # earth rate: at most 2.2e-3 of the rate at these positions (72 deg, 10 Hz), so 3e-3 relative is allowed.
    # Under vibration phi also swings by B = kz a |cos theta| / w about its mean (physics.md); the window opens
    # anywhere on that swing and closes at the first passage, so Tm may come up to 2 B / |rate| early.
    _, plan = rig.controller.plan(PROCEDURE, QUICK)
    a = rig.sim.devices.station.amplitude_ratio(10.0)
    for planned, p in zip(plan.measurements, session.points, strict=True):
        cos = abs(math.cos(math.radians(p.position_deg)))
        rate = abs(1.5e-4 + 0.56 * math.cos(math.radians(p.position_deg)))
        swing_s = 2 * 0.56 * a * cos / (2 * math.pi * p.freq_hz) / rate if p.freq_hz else 0.0
        assert abs(p.Tm_s - planned.nominal.Tm_s) <= 3e-3 * planned.nominal.Tm_s + swing_s
    assert out.analysis is not None and set(out.analysis.results) == {"integral", "baseline"}
    assert out.report_path.read_text().startswith("<!doctype html>")
    # Telemetry: progress reaches 1, the state ends finished, every point was announced.
    progress = [m["fraction"] for t, m in rig.messages if t == "progress"]
    assert progress[-1] == pytest.approx(1.0) and max(progress) <= 1.0
    assert [m["state"] for t, m in rig.messages if t == "state"][-1] == "finished"
    assert sum(t == "point" for t, _ in rig.messages) == 10
    assert any(t == "trace" and len(m["z_m"]) for t, m in rig.messages)
    # a listener who joins mid-run knows whose window and trace these are
    assert {m["session_uid"] for t, m in rig.messages if t in ("window", "trace")} == {out.session_uid}
    assert crank_hz(rig) == 0.0


def test_pause_takes_effect_at_a_safe_point_and_resume_continues(make_rig) -> None:
    rig = make_rig(speed=300.0)
    uid, _ = rig.controller.start(PROCEDURE, QUICK)
    wait_until(lambda: rig.controller.status()["done"] >= 1, 30)
    rig.controller.pause()
    wait_until(lambda: rig.controller.status()["state"] == "paused", 30)
    done = rig.controller.status()["done"]
    time.sleep(1.0)  # 300 s of station time: a window would have finished
    assert rig.controller.status()["done"] == done
    assert len(rig.store.load_session(uid).points) == done
    rig.controller.resume()
    out = rig.controller.wait(60)
    assert out.state == State.FINISHED and len(rig.store.load_session(uid).points) == 10


def test_abort_stops_the_table_and_keeps_every_finished_point(make_rig) -> None:
    rig = make_rig(speed=300.0)
    uid, _ = rig.controller.start(PROCEDURE, QUICK)
    wait_until(lambda: rig.controller.status()["done"] >= 2 and rig.controller.engine.freq_hz > 0, 30)
    rig.controller.abort()
    out = rig.controller.wait(30)
    assert out.state == State.ABORTED
    points = rig.store.load_session(uid).points
    assert 2 <= len(points) < 10 and [p.sequence for p in points] == list(range(len(points)))
    assert rig.store.sessions()[0]["status"] == "aborted"
    assert crank_hz(rig) == 0.0 and rig.sim.emulators["servo"].state == "SWITCH ON DISABLED"


def test_emergency_stop_quick_stops_the_crank_and_holds_the_head(make_rig) -> None:
    rig = make_rig(speed=300.0)
    uid, _ = rig.controller.start(PROCEDURE, QUICK)
    wait_until(lambda: rig.controller.engine.freq_hz > 0 and crank_hz(rig) > 9.9, 30)
    rig.controller.emergency_stop()
    out = rig.controller.wait(30)
    assert out.state == State.ESTOPPED
    assert crank_hz(rig) == 0.0
    assert rig.sim.devices.head.held  # no move until an operator releases it
    assert any(e["kind"] == "abort" and e["level"] == "critical" for e in rig.store.events(uid))


def test_a_device_fault_mid_session_fails_it_safely_without_losing_points(make_rig) -> None:
    rig = make_rig()
    uid, _ = rig.controller.start(PROCEDURE, QUICK)
    wait_until(lambda: rig.controller.status()["done"] >= 3, 30)
    rig.sim.emulators["counter"].inject(Fault.COUNTER_OVERFLOW)
    out = rig.controller.wait(30)
    assert out.state == State.FAILED
    assert any("counter overflow" in f for f in out.faults)
    points = rig.store.load_session(uid).points
    assert len(points) >= 3 and [p.sequence for p in points] == list(range(len(points)))
    assert crank_hz(rig) == 0.0


def test_reference_crossings_that_disagree_with_the_grating_are_a_fault(make_rig) -> None:
    # A read head stamping its crossings 1 ms late puts them 0.063 rad of phase off the grating's
    # mid-stroke crossing at 10 Hz: far beyond the 2e-3 rad tolerance of the cross-check.
    rig = make_rig(twin=default_twin().with_effect("readhead_latency", delta=1e-3))
    out = rig.controller.run(PROCEDURE, QUICK)
    assert out.state == State.FAILED
    assert any("TimingFault" in f and "grating" in f for f in out.faults)
    assert rig.store.load_session(out.session_uid).points == []  # the first point vibrates: nothing stored


def test_an_aborted_session_resumes_without_losing_or_repeating_points(make_rig) -> None:
    rig = make_rig(speed=300.0)
    uid, _ = rig.controller.start(PROCEDURE, QUICK)
    wait_until(lambda: rig.controller.status()["done"] >= 4, 60)
    rig.controller.abort()
    rig.controller.wait(30)
    before = rig.store.load_session(uid).points
    rig.controller.resume_session(uid)
    out = rig.controller.wait(60)
    assert out.state == State.FINISHED and out.session_uid == uid
    after = rig.store.load_session(uid).points
    assert after[: len(before)] == before
    assert [p.sequence for p in after] == list(range(10))
    assert len({p.point_id for p in after}) == 10


def test_sessions_run_back_to_back_without_a_reset(make_rig) -> None:
    """The master heartbeat is a timer of the clock for as long as the driver is connected (issue 25): between
    two sessions, with no run supervised, the drive keeps hearing its master and the next Start just works."""
    rig = make_rig()
    for _ in range(2):
        out = rig.controller.run(PROCEDURE, QUICK)
        assert out.state == State.FINISHED and out.faults == []
        rig.sim.devices.servo.watch(3 * CONFIG.servo.heartbeat_ms / 1000 + 0.1)  # > the drive's consumer time
        assert rig.controller.status()["drive_fault"] is None
    assert [s["status"] for s in rig.store.sessions()] == ["finished", "finished"]


def test_after_an_emergency_stop_a_reset_lets_the_next_run_start(make_rig) -> None:
    rig = make_rig(speed=300.0)
    rig.controller.start(PROCEDURE, QUICK)
    wait_until(lambda: rig.controller.engine.freq_hz > 0 and crank_hz(rig) > 9.9, 30)
    rig.controller.emergency_stop()
    assert rig.controller.wait(30).state == State.ESTOPPED
    assert rig.controller.status()["head_held"]
    rig.controller.reset()
    status = rig.controller.status()
    assert not status["head_held"] and status["drive_fault"] is None
    assert rig.controller.run(PROCEDURE, QUICK).state == State.FINISHED


def test_a_drive_whose_bus_was_lost_is_reconnected_by_a_reset(make_rig) -> None:
    rig = make_rig()
    servo = rig.sim.devices.servo
    rig.sim.emulators["servo"].silence_heartbeat()  # the drive falls silent: the watchdog latches the loss
    wait_until(lambda: rig.controller.status()["drive_fault"] is not None, 10)
    out = rig.controller.run(PROCEDURE, QUICK)
    assert out.state == State.FAILED  # refused at the first command, with the latched loss
    rig.sim.emulators["servo"].stop()  # the cause removed: a drive that works is back on the bus
    rig.sim.emulators["servo"] = ServoEmulator.from_config(
        rig.sim.devices.config.servo, servo._clock, rig.sim.world.crank
    )
    rig.sim.emulators["servo"].start()
    rig.controller.reset()
    assert rig.controller.status()["drive_fault"] is None and servo.state == "SWITCH ON DISABLED"


@pytest.mark.parametrize("stop", ["abort", "emergency_stop"])
@pytest.mark.parametrize("when", ["planning", "creating the session", "session open, start() returned"])
def test_a_stop_between_the_start_request_and_the_first_step_ends_the_run_before_anything_moves(
    make_rig, stop: str, when: str
) -> None:
    """A stop requested while a start is under way is the new run's (station.engine.runner.StopCount): it used to be
    lost
    when the run began and cleared the flags, and the run then moved the head and the table."""
    rig = make_rig()
    controller, moves = rig.controller, []
    devices = rig.sim.devices
    for name in ("move_index", "set_vibration"):
        original = getattr(devices, name)
        setattr(devices, name, lambda *a, _f=original, _n=name: (moves.append((_n, *a)), _f(*a))[1])

    def stopping(original):
        def hook(*args, **kwargs):
            result = original(*args, **kwargs)
            getattr(controller, stop)()  # from the thread under way, as a control thread's request lands then
            return result

        return hook

    owner, name = {
        "planning": (controller, "plan"),
        "creating the session": (rig.store, "create_session"),
        "session open, start() returned": (controller.supervisor, "watch"),  # on_open: the steps not begun
    }[when]
    setattr(owner, name, stopping(getattr(owner, name)))
    uid, _ = controller.start(PROCEDURE, QUICK)
    out = controller.wait(30)
    expected = State.ESTOPPED if stop == "emergency_stop" else State.ABORTED
    assert out is not None and (out.state, out.session_uid) == (expected, uid), out
    assert moves in ([], [("set_vibration", 0.0)])  # the head not moved, the table only ramped to rest (abort)
    assert crank_hz(rig) == 0.0 and rig.store.load_session(uid).points == []
    assert rig.store.sessions()[0]["status"] == "aborted"
    level = "critical" if stop == "emergency_stop" else "warning"
    assert [e["level"] for e in rig.store.events(uid) if e["kind"] == "abort"] == [level]
    # The stop was that run's only: the next start moves (after the reset an emergency stop asks for).
    delattr(owner, name)  # the hook (an instance attribute)
    if stop == "emergency_stop":
        controller.reset()
    moves.clear()
    controller.start(PROCEDURE, QUICK)
    wait_until(lambda: any(m[0] == "move_index" for m in moves), 30)
    controller.abort()
    assert controller.wait(30).state == State.ABORTED


def test_a_bare_start_of_a_design_that_cannot_work_is_refused_before_anything_moves(make_rig) -> None:
    """The panel dry-runs a design before its Start; a lab script's `start` on the control channel reaches the
    controller with no dry run, and is checked there: no session, no motion."""
    rig = make_rig()
    refused = r"refused: positions_deg = \[-360, 360, 0\][\s\S]*the design is singular"
    with pytest.raises(RefusedDesignError, match=refused):
        rig.controller.start(PROCEDURE, QUICK | {"positions_deg": [-360, 360, 0]})
    assert rig.store.sessions() == [] and not rig.controller.busy
    assert rig.controller.status()["freq_hz"] == 0.0 and rig.controller.status()["index_deg"] is None
