"""Electrodynamic shaker: the controller driver against its emulator over a pty and a sim:// line: the
test cycle on the world's slip table, the table's envelope refused before anything is sent, alarms, and
every fault becoming a typed error within a bounded time."""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from links import serve

from drivers.config import load_station_config
from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout, Disconnected, FrameError, LimitError
from drivers.pty_link import Fault
from drivers.shaker.driver import ShakerController
from drivers.shaker.emulator import ALARM_STOP_S, ShakerEmulator
from drivers.shaker.envelope import G_STANDARD_MPS2, check_random, random_sigmas
from station.twin.shaker_motion import ShakerMotion, sine_drive

from .conftest import make_world

pytestmark = pytest.mark.timeout(60)

SECTION = load_station_config(Path(__file__).parents[2] / "config" / "stations/shaker-sim.toml").extras["shaker"]
TIMEOUT_S = 0.3


@pytest.fixture
def shaker_rig(transport: str) -> Iterator[tuple[object, ShakerEmulator, ShakerController]]:
    world = make_world(speed=10.0, vibrate_hz=0.0)
    emu = ShakerEmulator(world, SECTION)
    try:
        shaker = ShakerController(serve(emu, transport), SECTION, baud=SECTION.baud, timeout_s=TIMEOUT_S).open()
        try:
            yield world, emu, shaker
        finally:
            shaker.close()
    finally:
        emu.close()


def wait_for(shaker: ShakerController, state: str, within_s: float = 3.0) -> None:
    deadline = time.monotonic() + within_s
    while shaker.status().state != state:
        assert time.monotonic() < deadline, f"not {state}: {shaker.status()}"
        time.sleep(0.02)


def test_a_sine_test_ramps_up_runs_and_ramps_down_on_the_table(shaker_rig) -> None:
    world, _, shaker = shaker_rig
    assert shaker.identify().startswith("THV710A")
    assert shaker.status().state == "IDLE"
    shaker.set_sine(20.0, 1.5)
    shaker.start(2.0)  # 0.2 s of wall time at 10x
    motion = world.shared("shaker", ShakerMotion)
    assert shaker.status().state == "RAMP_UP"
    wait_for(shaker, "RUN")
    st = shaker.check()
    assert st.mode == "SINE" and st.level_g == pytest.approx(1.5)
    ((a, _),) = motion.response([world.clock.now_s()], [0.0, 0.0125, 0.025], (None,))  # half a period apart
    assert max(abs(a[0])) <= 1.5 * G_STANDARD_MPS2 * (1 + 1e-12) and abs(a[0, 0] + a[0, 2]) < 1e-9
    shaker.stop(1.0)
    assert shaker.status().state == "RAMP_DOWN"
    wait_for(shaker, "IDLE")
    assert not motion.moving(world.clock.now_s())


@pytest.mark.parametrize(
    ("call", "field", "allowed"),
    [
        # 1.5 g at 2 Hz is 9.3 cm of stroke; the table has 2.55 cm (peak): at most 0.41 g there.
        (lambda s: s.set_sine(2.0, 1.5), "displacement_m", "at 2 Hz at most 0.41"),
        (lambda s: s.set_sine(8.0, 15.0), "velocity_mps", "at 8 Hz at most 10.2"),
        (lambda s: s.set_sine(3000.0, 1.0), "freq_hz", "1 .. 2500 Hz"),
        # 50 kN over 75 + 42 kg: 43.6 g of sine thrust, below the bare table's 100 g.
        (lambda s: s.set_sine(100.0, 50.0), "amp_g", "amp_g <= 43.58 g"),
        (lambda s: s.set_random(0.7, 1.0, 60.0), "displacement_m", "raise lo_hz"),  # 3 sigma: 40 mm
        (lambda s: s.set_random(0.7, 60.0, 10.0), "lo_hz", "< hi_hz = 10 Hz"),
        (lambda s: s.start(45.0), "ramp_s", "ramp_s <= 30 s"),
    ],
)
def test_the_envelope_is_refused_before_anything_is_sent(shaker_rig, call, field, allowed) -> None:
    _, emu, shaker = shaker_rig
    sent = list(emu.commands)
    with pytest.raises(LimitError) as info:
        call(shaker)
    assert info.value.field == field and allowed in str(info.value)
    assert emu.commands == sent


def test_random_displacement_is_the_flat_psd_integral() -> None:
    """0.7 g RMS over 10-60 Hz (seed 002): sigma_d^2 = PSD (10^-3 - 60^-3) / (3 (2 pi)^4), about 0.43 mm."""
    psd = (0.7 * G_STANDARD_MPS2) ** 2 / 50.0
    sd, sv = random_sigmas(0.7, 10.0, 60.0)
    assert sd == pytest.approx(math.sqrt(psd * (10.0**-3 - 60.0**-3) / 3.0) / (2 * math.pi) ** 2)
    assert sv == pytest.approx(math.sqrt(psd * (1 / 10.0 - 1 / 60.0)) / (2 * math.pi))
    check_random(SECTION, 0.7, 10.0, 60.0)  # within the table's envelope
    heavy = dataclasses.replace(SECTION, payload_kg=600.0)
    with pytest.raises(LimitError, match=r"payload_kg = 600.0.*<= 500 kg"):
        check_random(heavy, 0.7, 10.0, 60.0)


def test_the_controller_refuses_what_its_table_cannot_even_if_asked_directly(shaker_rig) -> None:
    _, _, shaker = shaker_rig
    with pytest.raises(DeviceFault, match="RANGE displacement_m"):
        shaker._transact("SINE 2.0 1.5")
    shaker.set_sine(20.0, 1.0)
    shaker.start(0.5)
    with pytest.raises(DeviceFault, match="BUSY"):
        shaker.set_sine(25.0, 1.0)


def test_an_alarm_stops_the_table_latches_and_refuses_a_start(shaker_rig) -> None:
    world, emu, shaker = shaker_rig
    shaker.set_sine(20.0, 1.0)
    shaker.start(0.5)
    emu.alarm("AMP_TEMP")
    with pytest.raises(DeviceFault, match="alarm AMP_TEMP") as info:
        shaker.check()
    assert info.value.field == "alarm"
    time.sleep(0.01)  # 0.1 s of station time: the trip stops the table within 20 ms
    assert not world.shared("shaker", ShakerMotion).moving(world.clock.now_s())
    with pytest.raises(DeviceFault, match="ALARM AMP_TEMP latched"):
        shaker.start(0.5)
    shaker.clear_alarm()
    shaker.start(0.5)
    assert shaker.check().state == "RAMP_UP"


def test_a_trip_or_an_abort_during_a_ramp_down_stops_the_table_at_once() -> None:
    """The slip table's model: a stop that brings the table to rest sooner than the ramp-down under way takes over
    (an amplifier trip, ABORT), the level continuous where it does (the ramps multiply: at the second stop's
    t_off its own factor is 1 to the last bit); a slower one changes nothing. Before, any stop during a ramp-down
    was ignored: a trip 1 s into a 10 s ramp-down left the table shaking for 9 s more."""
    motion = ShakerMotion()
    motion.start(sine_drive(20.0, 1.0, G_STANDARD_MPS2), 0.0, 0.5)
    motion.stop(5.0, 10.0)
    t_trip = 6.0
    before = motion.response([t_trip], [0.0], (None,))
    motion.stop(t_trip, ALARM_STOP_S)
    assert motion.response([t_trip], [0.0], (None,))[0][0] == before[0][0]
    assert motion.phase(t_trip + ALARM_STOP_S / 2) == "ramp_down"
    assert not motion.moving(t_trip + ALARM_STOP_S)
    ((a, _),) = motion.response([t_trip + ALARM_STOP_S], [0.0, 1.0], (None,))
    assert not a.any()
    motion.start(sine_drive(20.0, 1.0, G_STANDARD_MPS2), 10.0, 0.5)
    motion.stop(11.0, 1.0)
    motion.stop(11.5, 2.0)  # would end later: the 1 s ramp stands
    assert motion.moving(11.999) and not motion.moving(12.0)


def test_an_alarm_during_the_drivers_ramp_down_stops_the_table_within_the_trip_time(shaker_rig) -> None:
    world, emu, shaker = shaker_rig
    motion = world.shared("shaker", ShakerMotion)
    shaker.set_sine(20.0, 1.0)
    shaker.start(0.5)
    wait_for(shaker, "RUN")
    shaker.stop(20.0)  # 2 s of wall time at 10x
    emu.alarm("OVERTRAVEL")
    time.sleep(0.01)  # 0.1 s of station time: the trip stops the table within ALARM_STOP_S = 20 ms
    assert not motion.moving(world.clock.now_s())
    shaker.clear_alarm()
    shaker.start(0.5)
    wait_for(shaker, "RUN")
    shaker.stop(20.0)
    shaker.abort()
    time.sleep(0.01)
    assert not motion.moving(world.clock.now_s())


@pytest.mark.parametrize(
    ("fault", "error"),
    [
        (Fault.NO_ANSWER, DeviceTimeout),
        (Fault.GARBLE, FrameError),
        (Fault.TRUNCATE, FrameError),
        (Fault.CRC_ERROR, ChecksumError),
    ],
)
def test_faults_become_typed_errors_after_the_retries(shaker_rig, fault, error) -> None:
    _, emu, shaker = shaker_rig
    emu.inject(fault, count=3)  # one more than the retries
    t0 = time.monotonic()
    with pytest.raises(error, match="after 3 attempts"):
        shaker.status()
    assert time.monotonic() - t0 < 3 * TIMEOUT_S + 0.5
    assert shaker.status().state == "IDLE"  # and the link recovers


def test_start_is_not_retried_and_a_disconnect_is_reported(shaker_rig) -> None:
    _, emu, shaker = shaker_rig
    shaker.set_sine(20.0, 1.0)
    emu.inject(Fault.NO_ANSWER, count=1)
    with pytest.raises(DeviceTimeout, match="START"):
        shaker.start(0.5)
    assert [c for c in emu.commands if c.startswith("START")] == []  # ignored once, never sent again
    emu.inject(Fault.DISCONNECT)
    time.sleep(0.05)
    with pytest.raises(Disconnected):
        shaker.status()
