"""Temperature chamber: EI-Bisynch codec, the thermal model against an ODE solver, then the real driver
against its emulator over a pty and a sim:// line, every fault becoming a typed error within a bounded time.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest
from links import serve
from scipy.integrate import solve_ivp

from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout, Disconnected, FrameError, LimitError
from drivers.pty_link import Fault
from drivers.temperature_chamber import protocol as tc
from drivers.temperature_chamber.driver import TemperatureChamber
from drivers.temperature_chamber.emulator import PV_NOISE_C, ChamberEmulator, ChamberFault
from drivers.world import SimStation
from station.clock import VirtualClock
from station.twin.chamber_thermal import ramped_lag, time_to_band_s

pytestmark = pytest.mark.timeout(60)
TIMEOUT_S = 0.3
RETRIES = 2
# A failing command costs (1 + retries) timeouts; twice that is a generous bound on wall time.
FAIL_WITHIN_S = 2 * (1 + RETRIES) * TIMEOUT_S


# ---------------------------------------------------------------- codec


def test_messages_are_framed_as_ei_bisynch() -> None:
    assert tc.encode_read(1, "PV") == b"\x040011PV\x05"
    assert tc.encode_read(12, "SL") == b"\x041122SL\x05"
    frame = tc.block("SL", "25.00")
    assert frame[:1] == tc.STX and frame[-2:-1] == tc.ETX and frame[-1] == tc.bcc(b"SL25.00\x03")
    assert tc.encode_write(1, "SL", "25.00") == b"\x040011" + frame
    assert tc.decode_block(frame, "SL") == "25.00"
    assert tc.reply_length(frame + b"junk") == len(frame) and tc.reply_length(frame[:-1]) is None
    assert tc.reply_length(tc.ACK) == 1


def test_damaged_replies_raise_typed_errors() -> None:
    frame = tc.block("PV", "21.50")
    with pytest.raises(ChecksumError):
        tc.decode_block(frame[:-1] + bytes((frame[-1] ^ 1,)), "PV")
    with pytest.raises(FrameError, match="answers 'PV', not 'SL'"):
        tc.decode_block(frame, "SL")
    with pytest.raises(FrameError, match="not a reply"):
        tc.reply_length(b"\xfd\xafPV")


def test_ramped_lag_solves_the_first_order_lag_of_a_ramped_set_point() -> None:
    start_c, from_c, to_c, rate, tau = 18.0, 20.0, 80.0, 2.0 / 60, 300.0
    t_ramp = (to_c - from_c) / rate

    def rhs(t, y):
        u = from_c + rate * min(t, t_ramp)
        return [(u - y[0]) / tau]

    t = np.linspace(0.0, 3 * t_ramp, 61)
    ode = solve_ivp(rhs, (0, t[-1]), [start_c], t_eval=t, rtol=1e-10, atol=1e-10, max_step=10.0)
    product, sp = ramped_lag(t, start_c, from_c, to_c, rate, tau)
    assert np.max(np.abs(product - ode.y[0])) < 1e-6
    assert sp[0] == from_c and sp[-1] == to_c
    step, _ = ramped_lag(t, start_c, from_c, to_c, 0.0, tau)  # no rate limit: a step
    assert np.allclose(step, to_c + (start_c - to_c) * np.exp(-t / tau))
    t_band = time_to_band_s(from_c, to_c, rate, tau, 0.1)  # the soak estimate of planning
    in_band, _ = ramped_lag(t_band, from_c, from_c, to_c, rate, tau)
    assert float(in_band) == pytest.approx(to_c - 0.1, abs=1e-9)


# ---------------------------------------------------------------- driver against emulator


@pytest.fixture
def rig(transport: str) -> Iterator[tuple[SimStation, ChamberEmulator, TemperatureChamber]]:
    world = SimStation(clock=VirtualClock(50.0))
    emu = ChamberEmulator(world, time_constant_s=60.0)
    try:
        chamber = TemperatureChamber(serve(emu, transport), setpoint_min_c=-40, setpoint_max_c=80,
                                     ramp_max_c_per_min=10, timeout_s=TIMEOUT_S, retries=RETRIES).open()  # fmt: skip
        try:
            yield world, emu, chamber
        finally:
            chamber.close()
    finally:
        emu.close()


def test_set_point_ramps_and_the_product_follows(rig) -> None:
    world, emu, chamber = rig
    assert chamber.identity() == ">2408"
    assert chamber.temperature_c() == pytest.approx(20.0, abs=5 * PV_NOISE_C)
    chamber.set_ramp_rate(6.0)
    cmd_from = world.clock.now_s()
    chamber.set_setpoint(30.0)
    cmd_to = world.clock.now_s()
    assert chamber.setpoint_c() == 30.0 and chamber.ramp_rate_c_per_min() == 6.0
    st = chamber.status()
    assert st.ramping and not st.alarms and 20.0 <= st.working_setpoint_c < 30.0
    world.clock.sleep_s(60.0)
    # PV is the model plus sensor noise, the command and the query each at a station time between two clock readings.
    before = world.clock.now_s()
    pv = chamber.temperature_c()
    after = world.clock.now_s()
    lo, hi = (float(ramped_lag(dt, 20.0, 20.0, 30.0, 0.1, 60.0)[0]) for dt in (before - cmd_to, after - cmd_from))
    assert lo - 5 * PV_NOISE_C <= pv <= hi + 5 * PV_NOISE_C
    assert "SL 30.00" in emu.commands and "RR 6.00" in emu.commands


def test_limits_are_refused_before_anything_is_sent(rig) -> None:
    _, emu, chamber = rig
    sent = len(emu.commands)
    with pytest.raises(LimitError, match=r"setpoint_c = 95.0.*-40 \.\. 80 deg C"):
        chamber.set_setpoint(95.0)
    with pytest.raises(LimitError, match=r"ramp_c_per_min = 12.0.*<= 10 deg C/min"):
        chamber.set_ramp_rate(12.0)
    time.sleep(0.05)
    assert len(emu.commands) == sent


def test_controller_refusals_are_device_faults(rig) -> None:
    _, _, chamber = rig
    with pytest.raises(DeviceFault, match=r"SL = '500.00'.*NAK"):
        chamber.write("SL", "500.00")  # beyond the controller's own range
    with pytest.raises(DeviceFault, match="ZZ"):
        chamber.read("ZZ")


@pytest.mark.parametrize(
    ("fault", "error"),
    [(Fault.NO_ANSWER, DeviceTimeout), (Fault.GARBLE, FrameError), (Fault.TRUNCATE, FrameError),
     (Fault.CRC_ERROR, ChecksumError)],
)  # fmt: skip
def test_link_faults_become_typed_errors_within_bounded_time(rig, fault, error) -> None:
    """Each fault on every attempt is its typed error within the attempts' timeouts; then the link recovers. On a
    sim:// line the garbled reply comes byte by byte at 9600 baud (not in a pty's 64-byte bursts): the driver
    must let its tail pass, or each retry reads the previous reply's tail (before: 'not a reply' on all three
    attempts of the next read, 3 runs in 4)."""
    _, emu, chamber = rig
    emu.inject(fault, count=1 + RETRIES)
    t0 = time.monotonic()
    with pytest.raises(error, match="temperature chamber"):
        chamber.temperature_c()
    assert time.monotonic() - t0 < FAIL_WITHIN_S
    assert chamber.temperature_c() == pytest.approx(20.0, abs=5 * PV_NOISE_C)  # the link recovers


def test_one_damaged_reply_is_retried(rig) -> None:
    _, emu, chamber = rig
    emu.inject(Fault.CRC_ERROR, count=1)
    assert chamber.setpoint_c() == 20.0


def test_disconnect_is_seen_as_disconnected(rig) -> None:
    _, emu, chamber = rig
    emu.inject(Fault.DISCONNECT)
    t0 = time.monotonic()
    with pytest.raises(Disconnected):
        for _ in range(10):
            chamber.temperature_c()
    assert time.monotonic() - t0 < FAIL_WITHIN_S


def test_sensor_break_and_over_temperature_are_device_faults(rig) -> None:
    _, emu, chamber = rig
    emu.inject(ChamberFault.SENSOR_BREAK, count=None)
    with pytest.raises(DeviceFault, match=r"PV = 'S\.br'"):
        chamber.temperature_c()
    with pytest.raises(DeviceFault, match="sensor break"):
        chamber.check_alarms()
    assert np.isnan(chamber.status().temperature_c)
    emu.clear_fault(ChamberFault.SENSOR_BREAK)
    emu.inject(ChamberFault.OVER_TEMPERATURE)
    time.sleep(0.05)
    with pytest.raises(DeviceFault, match=r"alarms = 'over-temperature \(AL1\)'"):
        chamber.check_alarms()
    chamber.acknowledge_alarms()
    chamber.check_alarms()
    assert chamber.status().alarms == ()
