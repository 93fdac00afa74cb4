"""Voltmeter: SCPI reply parsing, then the real driver against its emulator over a pty and a sim:// line, reading the
tumbled accelerometer of seed 001 at the head's angle and the chamber's temperature.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterator

import numpy as np
import pytest
from links import serve

from drivers.errors import DeviceFault, DeviceTimeout, Disconnected, FrameError, LimitError
from drivers.pty_link import Fault
from drivers.temperature_chamber.emulator import ChamberEmulator
from drivers.voltmeter import driver as vm
from drivers.voltmeter.emulator import METER_NOISE_OF_RANGE, VoltmeterEmulator, VoltmeterFault, accelerometer
from drivers.world import SimStation
from station.clock import VirtualClock
from station.twin.pendulous_accelerometer import AccelerometerModel, output_v

pytestmark = pytest.mark.timeout(60)
TIMEOUT_S = 0.3
RETRIES = 2
FAIL_WITHIN_S = 2 * (1 + RETRIES) * TIMEOUT_S  # (1 + retries) timeouts, with a factor 2 of slack
QUIET = dataclasses.replace(AccelerometerModel(), noise_g_rt_hz=0.0, drift_g_per_s=0.0)


def test_readings_are_parsed_strictly() -> None:
    assert vm.parse_readings(b"+1.35012345E+00,-2.00000000E-03", 2) == pytest.approx([1.35012345, -0.002])
    for bad in (b"+1.35012345E+00", b"+1.35\xff12345E+00,+1.0E+00", b"+1.3501", b"1.35E+00,+1.0E+00"):
        with pytest.raises(FrameError, match="expected 2 NR3 readings"):
            vm.parse_readings(bad, 2)
    assert vm.reading_s(10, 5, 50.0) == pytest.approx(2.0)  # 5 x 2 conversions x 10 PLC of 20 ms


@pytest.fixture
def rig(transport: str) -> Iterator[tuple[SimStation, VoltmeterEmulator, vm.Voltmeter]]:
    world = SimStation(clock=VirtualClock(100.0))
    emu = VoltmeterEmulator(world)
    try:
        meter = vm.Voltmeter(serve(emu, transport), timeout_s=TIMEOUT_S, retries=RETRIES, clock=world.clock).open()
        try:
            yield world, emu, meter
        finally:
            meter.close()
    finally:
        emu.close()


def _head_at(world: SimStation, angle_deg: float) -> None:
    world.index_command_move(angle_deg, world.clock.now_s())
    while world.index_busy(world.clock.now_s()):
        time.sleep(0.01)


def test_reading_is_the_accelerometer_at_the_heads_angle(rig) -> None:
    world, emu, meter = rig
    accel = accelerometer(world)
    accel.set_model(QUIET)
    assert "MODEL 2002" in meter.identity()
    meter.configure(2.0, 1.0, 4)
    meter_sigma_v = METER_NOISE_OF_RANGE * 2.0 * math.sqrt(10.0)
    for angle_deg in (0.0, 90.0, 180.0):
        _head_at(world, angle_deg)
        r = meter.read()
        assert r.end_s - r.start_s >= vm.reading_s(1.0, 4, 50.0)  # the meter integrates in station time
        expected = output_v(QUIET, math.radians(angle_deg), 20.0, accel.branch, accel.launch_g)
        assert np.all(np.abs(r.volts - expected) < 5 * meter_sigma_v), angle_deg
    assert ":SAMP:COUN 4" in emu.commands


def test_reading_follows_the_chamber_temperature(rig) -> None:
    world, _, meter = rig
    accel = accelerometer(world)
    accel.set_model(QUIET)
    with ChamberEmulator(world, time_constant_s=1.0) as chamber:
        chamber.thermal.command(world.clock.now_s(), target_c=60.0, rate_c_per_min=0.0)
        world.clock.sleep_s(30.0)  # 30 time constants
        volts = meter.measure(2.0, 1.0, 1).volts[0]
    expected = output_v(QUIET, 0.0, 60.0, accel.branch, accel.launch_g)
    assert volts == pytest.approx(expected, abs=1e-5)
    assert abs(expected - output_v(QUIET, 0.0, 20.0, accel.branch, accel.launch_g)) > 0.02  # beta_T1: 2 % over 40 C


def test_settings_outside_the_instrument_are_refused_before_sending(rig) -> None:
    _, emu, meter = rig
    sent = len(emu.commands)
    with pytest.raises(LimitError, match=r"range_v = 5.0.*0.2, 2, 20, 200, 1000 V"):
        meter.configure(5.0, 1.0, 1)
    with pytest.raises(LimitError, match=r"nplc = 100.*0.01 \.\. 50"):
        meter.configure(2.0, 100, 1)
    with pytest.raises(LimitError, match="samples = 0"):
        meter.configure(2.0, 1.0, 0)
    time.sleep(0.05)
    assert len(emu.commands) == sent


def test_errors_in_the_queue_are_reported(rig) -> None:
    _, _, meter = rig
    meter.send(":SENS:VOLT:DC:NPLC 99")
    meter.send(":FOO:BAR")
    assert meter.errors() == ['-222,"Data out of range"', '-113,"Undefined header"']
    assert meter.errors() == []


@pytest.mark.parametrize(
    ("fault", "error"), [(Fault.NO_ANSWER, DeviceTimeout), (Fault.GARBLE, FrameError), (Fault.TRUNCATE, FrameError)]
)
def test_link_faults_become_typed_errors_within_bounded_time(rig, fault, error) -> None:
    _, emu, meter = rig
    meter.configure(2.0, 1.0, 2)
    emu.inject(fault, count=1 + RETRIES)
    t0 = time.monotonic()
    with pytest.raises(error, match="voltmeter"):
        meter.read()
    assert time.monotonic() - t0 < FAIL_WITHIN_S
    assert meter.read().volts.size == 2  # the link recovers


def test_disconnect_is_seen_as_disconnected(rig) -> None:
    _, emu, meter = rig
    emu.inject(Fault.DISCONNECT)
    t0 = time.monotonic()
    with pytest.raises(Disconnected):
        for _ in range(10):
            meter.identity()
    assert time.monotonic() - t0 < FAIL_WITHIN_S


def test_overload_is_a_device_fault(rig) -> None:
    _, emu, meter = rig
    meter.configure(2.0, 1.0, 1)
    emu.inject(VoltmeterFault.OVERLOAD)
    with pytest.raises(DeviceFault, match=r"input overload.*2 V range"):
        meter.read()
    with pytest.raises(DeviceFault, match=r"0.21 V on the 0.2 V range"):
        meter.measure(0.2, 1.0, 1)  # 1.35 V of output at 0 deg
