"""A lost counter ARM reply (issue 31, deliverable 2): the board carried the ARM out, the driver never heard so
(ReplyLost, "the board may be armed"). The point is measured again, the board aborted before it is armed again,
and the session finishes with every point stored: on the station's own counter (drivers.station.measure_window)
and on the second instrument's (seed 003, CounterTimer.measure). Deterministic simulated stations."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from drivers.config import load_station_config
from drivers.counter_timer import protocol as c
from drivers.counter_timer.emulator import CounterEmulator
from drivers.errors import ReplyLost
from drivers.pty_link import Fault
from drivers.station import simulated_station
from station.cli.controller import StationController
from station.engine.planning import Plan, plan_procedure
from station.engine.registry import get_procedure
from station.engine.runner import Engine, State
from station.session import PointRecord
from station.store import SessionStore
from station.twin.config import default_twin
from tests.procedure_runs import CONFIG, procedure_spec

NAMES = {c.ARM: "ARM", c.ABORT: "ABORT", c.STATUS_Q: "STATUS?"}


def _spy(emulator: CounterEmulator) -> list[tuple[str, bool]]:
    """The commands the board carries out, in order, each with whether its reply was lost."""
    seen: list[tuple[str, bool]] = []
    command = emulator._command

    def spied(cmd: int, payload: bytes) -> None:
        seen.append((NAMES.get(cmd, hex(cmd)), emulator._reply_lost))
        command(cmd, payload)

    emulator._command = spied  # type: ignore[method-assign]
    return seen


def _planned_points(plan: Plan) -> int:
    return sum(isinstance(s.nominal, PointRecord) for s in plan.steps)


def _check_recovery(seen: list[tuple[str, bool]]) -> None:
    (lost,) = [i for i, (_, was_lost) in enumerate(seen) if was_lost]
    assert seen[lost][0] == "ARM", seen
    after = [name for name, _ in seen[lost + 1 :]]
    assert "ARM" in after, seen
    assert "ABORT" in after[: after.index("ARM")], f"the board was armed again without an abort: {seen}"


def _check_repeat(events: list[dict], n: int = 1) -> None:
    repeats = [e["message"] for e in events if e["kind"] == "repeat"]
    assert len(repeats) == n, events
    assert all("ReplyLost" in m and "ARM" in m and "measuring it again (1 of" in m for m in repeats), repeats


def test_a_lost_arm_reply_leaves_the_board_armed_and_measure_aborts_it() -> None:
    cfg = load_station_config(CONFIG / "stations/vibration-sim.toml")
    with simulated_station(cfg, default_twin(), seed=11) as sim, sim.devices.clock.party("test"):
        emulator, board = sim.emulators["counter"], sim.devices.counter
        emulator.inject(Fault.LOST_REPLY)
        with pytest.raises(ReplyLost, match="the board may be armed: abort"):
            board.arm(1000)
        assert board.status()["state"] in ("armed", "counting")  # carried out: only the reply was lost
        board.abort()
        emulator.inject(Fault.LOST_REPLY)
        with pytest.raises(ReplyLost):
            board.measure(1000)
        assert board.status()["state"] == "idle"  # measure() aborted it: the next ARM is not refused as busy
        assert board.measure(1000).pulses == 1000


def test_a_lost_arm_reply_is_aborted_and_the_point_measured_again(tmp_path: Path) -> None:
    name = "integral_precession.integer_periodic_vibration"
    cfg = load_station_config(CONFIG / "stations/vibration-sim.toml")
    spec = procedure_spec(name)
    shorter = {"positions_deg": [0, 180], "freqs_hz": [10], "window_s": 10}
    params = spec.validate(
        tomllib.loads((CONFIG / "procedures" / f"{name}.toml").read_text()).get("params", {}) | shorter
    )
    plan = plan_procedure(spec, params, cfg.station_model())
    with (
        simulated_station(cfg, default_twin(), seed=11) as sim,
        SessionStore(tmp_path / "station.sqlite") as store,
        sim.devices.clock.party("engine"),
    ):
        board = sim.emulators["counter"]
        seen = _spy(board)

        def publish(topic: str, msg: dict) -> None:
            if topic == "point" and msg["sequence"] == 0:  # between windows: the board's next command is an ARM
                board.inject(Fault.LOST_REPLY)

        engine = Engine(sim.devices, store, publish=publish)
        uid, _ = engine.run(spec, plan, instrument_serial="PIGA-RT-1")
        assert engine.progress.state == State.FINISHED, engine.progress.faults
        points = store.load_session(uid, with_raw=False).points
        assert [p.sequence for p in points] == list(range(_planned_points(plan))), points
        assert board.state != c.ARMED
        _check_recovery(seen)
        _check_repeat(store.events(uid))


def test_a_lost_arm_reply_on_the_second_instrument_is_aborted_and_the_point_measured_again(tmp_path: Path) -> None:
    config = load_station_config(CONFIG / "stations/dual-sim.toml")
    quick = {"precession_rev": 1 / 64, "alignment_rev": 1 / 64, "settle_s": 0.0, "setup1_n": 6, "setup2_n": 6,
             "calibration_schemes": "none"}  # fmt: skip
    with (
        simulated_station(config, default_twin(), seed=4) as sim,
        SessionStore(tmp_path / "station.sqlite") as store,
    ):
        board = sim.emulators["second_instrument"]
        seen = _spy(board)
        board.inject(Fault.LOST_REPLY)  # its first command is the first B window's ARM
        controller = StationController(sim.devices, store, config.station_model(), reports_dir=tmp_path)
        outcome = controller.run("multiposition", quick)
        assert outcome.state == State.FINISHED, outcome.faults
        spec = get_procedure("multiposition")
        plan = plan_procedure(spec, spec.validate(quick), config.station_model())
        points = store.load_session(outcome.session_uid, with_raw=False).points
        assert [p.sequence for p in points] == list(range(_planned_points(plan))), points
        _check_recovery(seen)
        _check_repeat(store.events(outcome.session_uid))
