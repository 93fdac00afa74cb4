"""Seed 003's second instrument: its counter/timer channel against the emulator fed by PIGA B on the simulated
fixture (over a pty and a sim:// line), every injected fault a typed error within a bounded time, the fixture's
re-installation, and bad input refused before anything moves."""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from links import serve

from drivers.config import ConfigError, load_station_config
from drivers.config import SerialSection as Section
from drivers.counter_timer.driver import CounterTimer
from drivers.counter_timer.emulator import CounterEmulator
from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout, Disconnected, DriverError, FrameError
from drivers.indexing_head.driver import IndexingHead
from drivers.indexing_head.emulator import IndexingEmulator
from drivers.pty_link import Fault
from drivers.registry import device_kinds
from drivers.second_instrument.emulator import FIXTURE, INSTRUMENT_B, SEAT_ERRORS_RAD, DualFixture, InstrumentOnHead
from drivers.station import simulated_station
from drivers.world import SimStation
from station.cli.controller import StationController
from station.clock import VirtualClock
from station.engine.context import ValidationError
from station.engine.params import ParameterError
from station.engine.planning import plan_procedure
from station.engine.registry import get_procedure
from station.engine.runner import State
from station.store import SessionStore
from station.twin.config import TwinConfig
from station.twin.fixture import mounted_twin, pose_rad
from station.twin.inputs import instrument_rate_radps

pytestmark = pytest.mark.timeout(120)

CONFIG_DIR = Path(__file__).parents[2] / "config"
TWIN = TwinConfig.from_toml(CONFIG_DIR / "twins" / "multiposition.toml")
KIND = device_kinds()["second_instrument"]
SILENCE_S = 3.0  # drivers.counter_timer.driver default: a silent board is a DeviceTimeout after this


@pytest.fixture
def channel(transport: str) -> Iterator[tuple[SimStation, object, object]]:
    """World at rest, PIGA B's counter emulator, and the driver DEVICE_KIND opens on it. The emulator is the
    one KIND.emulate starts on a pty (the engine tests below go through it), here not started yet so that it
    can serve either link."""
    world = SimStation(TWIN, VirtualClock(50.0), seed=2)
    emulator = CounterEmulator(InstrumentOnHead(world, world.shared(FIXTURE, lambda: DualFixture(world))), baud=921_600)
    emulator.name = "second-counter-emulator"
    try:
        board = KIND.open(Section(port=serve(emulator, transport), baud=921_600), world.clock)
        try:
            yield world, emulator, board
        finally:
            board.close()
    finally:
        emulator.close()


def test_second_channel_counts_piga_b_in_its_pose(channel) -> None:
    """B's window gives B's rate at its pose on the head (seat error and own input-axis error included).
    The head at 300 deg puts B at 30 deg: 4096 pulses at about 0.48 rad/s take 3 s of station time."""
    world, _, board = channel
    world.index_command_move(300.0, world.clock.now_s())
    while world.index_busy(world.clock.now_s()):
        time.sleep(0.01)
    fixture = world.shared(FIXTURE, lambda: None)
    result = board.measure(4096)
    twin_b = mounted_twin(world.twin, fixture.mount_rad("B"), INSTRUMENT_B)
    expected = float(instrument_rate_radps(math.radians(300.0), 0.0, 0.0, twin_b))
    measured = 2 * math.pi * result.pulses / (16384 * result.Tm_s)
    window_noise = TWIN.noise.rate_noise_radps * math.sqrt(TWIN.noise.rate_noise_ref_s / result.Tm_s)
    assert abs(measured - expected) < 5 * window_noise
    assert fixture.mount_rad("B") == pytest.approx(pose_rad(2) + SEAT_ERRORS_RAD[2] + fixture.ia_error_rad["B"])


def test_reinstalling_moves_both_instruments(channel) -> None:
    world, _, _ = channel
    fixture = world.shared(FIXTURE, lambda: None)
    world.operator.perform("re-install", {"fixture_poses": [4, 3]})
    assert world.twin.param("mount_misalignment", "dtheta_mount") == pytest.approx(fixture.mount_rad("A"))
    assert fixture.mount_rad("A") == pytest.approx(pose_rad(4) + SEAT_ERRORS_RAD[4] + fixture.ia_error_rad["A"])
    for bad in ([1, 1], [0, 2], "4,3", [4]):
        with pytest.raises(DriverError, match="fixture_poses") as info:
            world.operator.perform("re-install", {"fixture_poses": bad})
        assert "two different poses" in str(info.value)


@pytest.mark.parametrize(
    ("fault", "error"),
    [(Fault.CRC_ERROR, ChecksumError), (Fault.GARBLE, FrameError), (Fault.TRUNCATE, FrameError),
     (Fault.COUNTER_OVERFLOW, DeviceFault), (Fault.DISCONNECT, Disconnected)],
)  # fmt: skip
def test_faults_during_a_window_are_typed_errors_in_bounded_time(channel, fault, error) -> None:
    _, emulator, board = channel
    board.arm(10_000_000)  # about 6 station hours at B's rate: it is under way when the fault comes
    while board.next_event().kind != "open":
        pass
    emulator.inject(fault)
    t0 = time.monotonic()
    with pytest.raises(error):
        board.wait_window(timeout_s=5.0)
    assert time.monotonic() - t0 < SILENCE_S + 1.0


def test_a_host_stall_longer_than_a_tick_wrap_leaves_the_window_intact(channel) -> None:
    """A static window of B with its input axis horizontal (the head at 0) lasts a quarter of an hour of
    station time; stalls of the host process skip 650 s at once (0.65 s of wall time at 1000x, seen on this
    shared machine), three wraps of the 32-bit 50 ns stamps. The stamps must still unwrap to the true length."""
    world, emulator, board = channel
    stalls = []

    def stall(ev) -> None:
        if ev.kind in ("open", "heartbeat") and len(stalls) < 2:
            stalls.append(ev.kind)
            world.clock.advance_s(650.0)

    board.arm(512)
    result = board.wait_window(on_event=stall)
    assert result.Tm_s > 650.0
    assert result.Tm_s == pytest.approx(emulator.window.close_s - emulator.window.open_s, abs=1e-7)


def test_a_host_stall_in_a_vibration_window_keeps_its_crossings_in_order_and_once(transport) -> None:
    """The counter emulator changed for the stall above: in a 10 Hz window the 650 s skipped hold 6500 reference
    crossings, more than the board's FIFO takes at once. They must still arrive in order, each once, with no
    heartbeat stamped beyond them: every period 0.1 s and t2 = t1 + Np T - Tm to the 50 ns tick. After a deferral
    at a crossing the emulator catches up in steps of MAX_STAMP_GAP_S = 100 s, 1000 periods at 10 Hz, so each step
    ends on a crossing: (t0, t1] and (t1, t2] must not both miss it (on a sim:// line they did, about 1 run in 12,
    until a crossing's time stopped depending on the interval asked: drivers.world.SimStation.reference_crossings_s)."""
    world = SimStation(TWIN, VirtualClock(500.0), seed=1)
    world.crank.command_speed(2 * math.pi * 10.0, 1e6, world.clock.now_s())
    with contextlib.closing(CounterEmulator(world, baud=3_000_000)) as emulator:
        board = CounterTimer(serve(emulator, transport), clock=world.clock).open()
        stalled = []

        def stall(ev) -> None:
            if ev.kind == "open" and not stalled:
                stalled.append(world.clock.now_s())
                world.clock.advance_s(650.0)

        try:
            result = board.measure(2_000_000, on_event=stall, timeout_s=60.0)  # about 1370 s of station time
        finally:
            board.close()
    assert result.Tm_s == pytest.approx(emulator.window.close_s - emulator.window.open_s, abs=1e-7)
    assert np.allclose(np.diff(result.crossings_s), 0.1, atol=1e-6)
    assert result.t1_s + result.Np * 0.1 - result.Tm_s == pytest.approx(result.t2_s, abs=2 * 50e-9)


def test_a_host_stall_during_a_head_move_is_not_a_settling_timeout(transport) -> None:
    """A seed-003 session moves the head some 140 times; a host stall during a move skips 200 s of station
    time (0.2 s at 1000x), more than the head's 120 s move timeout. The head is then idle at its target,
    which is settling, not a timeout."""
    world = SimStation(TWIN, VirtualClock(10.0), seed=1)
    with contextlib.closing(IndexingEmulator(world)) as emulator:
        head = IndexingHead(serve(emulator, transport), settle_time_s=2.0, clock=world.clock).open()
        try:
            timer = threading.Timer(0.1, world.clock.advance_s, (200.0,))  # 1 s into the 5 s move
            timer.start()
            assert head.move_to(100.0) == pytest.approx(100.0)
            timer.join()
        finally:
            head.close()


def test_silent_board_is_a_timeout(channel) -> None:
    _, emulator, board = channel
    emulator.inject(Fault.NO_ANSWER, count=None)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="ARM"):
        board.arm(1000)
    assert time.monotonic() - t0 < 1.0


# ---- through the engine -------------------------------------------------------------------------------

QUICK = {"precession_rev": 1 / 64, "alignment_rev": 1 / 64, "settle_s": 0.0, "setup1_n": 6, "setup2_n": 6,
         "calibration_schemes": "none"}  # fmt: skip


@pytest.fixture
def dual_station(tmp_path):
    config = load_station_config(CONFIG_DIR / "stations/dual-sim.toml")
    sim = simulated_station(config, TWIN, seed=4)
    store = SessionStore(tmp_path / "station.sqlite")
    controller = StationController(sim.devices, store, config.station_model(), reports_dir=tmp_path)
    try:
        yield sim, controller
    finally:
        if controller.busy:
            controller.abort()
            controller.wait(30)
        sim.close()
        store.close()


def test_a_dead_second_channel_fails_the_session_naming_it(dual_station) -> None:
    sim, controller = dual_station
    sim.emulators["second_instrument"].inject(Fault.NO_ANSWER, count=None)
    outcome = controller.run("multiposition", QUICK)
    assert outcome.state == State.FAILED
    (fault,) = outcome.faults
    # ReplyLost is the DeviceTimeout of a lost reply, tried again (issue 13) before the session fails on it
    port = sim.emulators["second_instrument"].port
    assert fault.startswith(f"ReplyLost: second instrument's counter/timer on {port}:") and "ARM" in fault


def test_abort_during_a_second_instrument_window_leaves_its_board_idle(dual_station) -> None:
    sim, controller = dual_station
    uid, _ = controller.start("multiposition", QUICK | {"precession_rev": 1 / 4})  # B: hours of station time
    deadline = time.monotonic() + 60
    while not controller.status()["key"].endswith("-B"):  # the first B window: 0 deg, its axis horizontal
        assert time.monotonic() < deadline
        time.sleep(0.01)
    controller.abort()
    assert controller.wait(30).state == State.ABORTED
    assert sim.devices.device("second_instrument").status()["state"] == "idle"
    stored = [p.point_id for p in controller.store.load_session(uid, with_raw=False).points]
    assert stored and not any(k.endswith("-B") for k in stored)  # the abort came inside B's window


# ---- bad input, before anything moves ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("params", "named"),
    [
        ({"setup1_n": 5}, "'setup1_n' = 5: out of range, allowed int in [6, 72]"),
        ({"precession_rev": 0}, "'precession_rev' = 0: out of range, allowed float in [0.015625, 100] rev"),
        ({"calibration_schemes": "all"}, "'calibration_schemes' = 'all': expected one of 'both', 'equal_angle'"),
        ({"harmonics": 5}, "'harmonics' = 5: out of range, allowed int in [1, 4]"),
        ({"model": "cubic"}, "'model' = 'cubic': expected one of 'seed003', 'physics'"),
    ],
)
def test_bad_parameters_name_the_field_value_and_allowed(params, named) -> None:
    with pytest.raises(ParameterError) as info:
        get_procedure("multiposition").validate(params)
    assert named in str(info.value)


def test_a_station_without_the_second_instrument_is_refused_in_planning() -> None:
    spec = get_procedure("multiposition")
    model = load_station_config(CONFIG_DIR / "stations/vibration-sim.toml").station_model()
    with pytest.raises(ValidationError, match="device = 'second_instrument' is not allowed: a device of this"):
        plan_procedure(spec, spec.validate({}), model)


def test_dry_run_shows_the_hours_where_an_input_axis_is_horizontal() -> None:
    """With B 90 deg from A, the four-pose positions at 0 and 180 deg put B's input axis horizontal: its
    rate is about k0, so a 10 pi window takes 2 pi 5 / (k0 + kz cos 90.0) of the planning model, days."""
    spec = get_procedure("multiposition")
    model = load_station_config(CONFIG_DIR / "stations/dual-sim.toml").station_model()
    est = plan_procedure(spec, spec.validate({}), model).key_estimates_s()
    slow = 2 * math.pi * 5 / abs(model.nominal_rate_radps(90.0))
    assert est["S1-01-0deg-B"] == pytest.approx(slow, rel=1e-3) and slow > 24 * 3600
    assert est["S1-01-0deg-A"] < 600 and est["S1-AL1-90"] > 4 * 3600


def test_a_bad_section_names_the_key(tmp_path) -> None:
    text = (CONFIG_DIR / "stations/dual-sim.toml").read_text().replace("baud = 921_600", "baud = 50")
    text = text.replace('eds = "../eds/', f'eds = "{CONFIG_DIR}/eds/')
    path = tmp_path / "station.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"\[second_instrument\] baud = 50: not allowed \(allowed: 300 <= value"):
        load_station_config(path)
