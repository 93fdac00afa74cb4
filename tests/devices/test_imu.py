"""Strapdown IMU: the real driver against its emulator over a pty and a sim:// line: what a resting and a rocking IMU
stream, gaps, and every fault becoming a typed error within a bounded time."""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from links import serve

from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout, Disconnected, DriverError, FrameError, LimitError
from drivers.imu.driver import ImuRecording, StrapdownImu
from drivers.imu.emulator import FIFO_BYTES, ImuEmulator
from drivers.pty_link import Fault
from station.twin.shaker_motion import ShakerMotion, sine_drive

from .conftest import make_world

pytestmark = pytest.mark.timeout(60)

Rig = tuple[object, ImuEmulator, StrapdownImu]


@pytest.fixture
def imu_rig(transport: str) -> Iterator[Callable[..., Rig]]:
    with contextlib.ExitStack() as stack:  # each rig: driver closed, then its emulator

        def make(speed: float = 5.0, silence_s: float = 0.5, fifo_bytes: int = FIFO_BYTES) -> Rig:
            world = make_world(speed=speed, vibrate_hz=0.0)
            emu = ImuEmulator(world, fifo_bytes=fifo_bytes)
            stack.callback(emu.close)
            imu = StrapdownImu(
                serve(emu, transport), rate_hz=200, timeout_s=0.3, silence_s=silence_s, clock=world.clock
            )
            stack.callback(imu.close)
            return world, emu, imu.open()

        yield make


def record(imu: StrapdownImu, duration_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rec = ImuRecording(imu.dt_s)
    imu.start_stream()
    rec.add(imu.read_block())
    end = rec.last_t_s + duration_s
    while rec.last_t_s < end:
        rec.add(imu.read_block())
    imu.stop_stream()
    return rec.arrays()


def test_a_resting_imu_senses_gravity_and_the_earth_rate(imu_rig) -> None:
    world, emu, imu = imu_rig()
    assert imu.info is not None and imu.info.rate_hz == 200 and imu.info.gyro_lsb_rad == 1e-9
    t, dtheta, dv = record(imu, 4.0)
    assert np.allclose(np.diff(t), 0.005, atol=1e-9)  # every sample, on the 200 Hz grid
    st, twin = world.twin.station, emu.twin
    lat = st.latitude_rad
    duration = t[-1] - t[0] + 0.005
    # Off the shaker the IMU lies level in ENU: f = (0, 0, g), omega = omega_ie (0, cos L, sin L).
    # Tolerances: the residual bias plus 5 sigma of the white noise over the record.
    f_tol = np.abs(twin.accel_bias_mps2) + 5 * twin.accel_noise_mps2_rthz / math.sqrt(duration)
    w_tol = np.abs(twin.gyro_bias_radps) + 5 * twin.gyro_arw_rad_rts / math.sqrt(duration)
    assert np.all(np.abs(dv.sum(axis=0) / duration - [0, 0, st.g_mps2]) < f_tol)
    earth = st.earth_rate_radps * np.array([0.0, math.cos(lat), math.sin(lat)])
    assert np.all(np.abs(dtheta.sum(axis=0) / duration - earth) < w_tol)


def test_the_dampers_rock_the_imu_as_in_seed_fig5(imu_rig) -> None:
    """Pose 5 (Fig. 3e): y along the slip table, x along the rocking axis; 1 g at 20 Hz rocks the IMU at
    about 36 deg/s, rate and force 3 pi / 5 apart (seed 002 eq. 27)."""
    world, emu, imu = imu_rig(speed=10.0)
    world.operator.perform("mount", {"fixture_pose": 5})
    motion = world.shared("shaker", ShakerMotion)
    motion.start(sine_drive(20.0, 1.0, 9.80665), world.clock.now_s(), 0.5)
    time.sleep(0.1)  # 1 s of station time: past the ramp
    t, dtheta, dv = record(imu, 2.0)
    omega_x, f_y = dtheta[:, 0] / 0.005, dv[:, 1] / 0.005
    # Interval means of a 20 Hz line at 200 Hz are the line times sinc(0.1) = 0.984, delayed by half a sample.
    basis = np.column_stack([np.sin(2 * np.pi * 20 * (t - 0.0025)), np.cos(2 * np.pi * 20 * (t - 0.0025))])
    (ws, wc), *_ = np.linalg.lstsq(basis, omega_x - omega_x.mean(), rcond=None)
    (fs, fc), *_ = np.linalg.lstsq(basis, f_y - f_y.mean(), rcond=None)
    h = emu.twin.dampers
    expected_rate = abs(h.rocking_gain(20.0)) * 2 * np.pi * 20 * 9.80665  # |G| w a, per 1 g of table
    assert math.hypot(ws, wc) / np.sinc(0.1) == pytest.approx(expected_rate, rel=0.01)
    assert math.degrees(expected_rate) == pytest.approx(36.0, rel=0.03)
    shift = (math.atan2(fc, fs) - math.atan2(wc, ws) + math.pi) % (2 * math.pi) - math.pi
    assert abs(shift) == pytest.approx(3 * math.pi / 5, abs=0.05)  # the sign is the axes' convention
    assert math.hypot(fs, fc) / np.sinc(0.1) == pytest.approx(abs(h.transmissibility(20.0)) * 9.80665, rel=0.01)


def test_a_gap_is_counted_and_a_recording_refuses_it(imu_rig) -> None:
    _, emu, imu = imu_rig()
    imu.start_stream()
    imu.read_block()
    emu.drop(7)
    lost, deadline = 0, time.monotonic() + 2.0
    while lost == 0 and time.monotonic() < deadline:
        block = imu.read_block()
        lost += block.lost
    assert lost == 7
    with pytest.raises(DriverError, match="7 samples lost"):
        ImuRecording(imu.dt_s).add(block)


@pytest.mark.parametrize("transport", ["pty"])  # a sim:// line paces in station time: 400x is not too fast there
def test_a_line_faster_than_its_share_drops_samples_visibly(imu_rig) -> None:
    """At 400x real time 200 Hz frames need 3.2 MB/s, beyond the 3 Mbaud line: the IMU drops, the
    driver counts the gap."""
    _, emu, imu = imu_rig(speed=400.0, fifo_bytes=1 << 16)
    imu.start_stream()
    lost, end = 0, time.monotonic() + 4.0  # the gap shows once the IMU's buffer (0.2 s of line) is read
    while lost == 0 and time.monotonic() < end:
        lost += imu.read_block().lost
    imu.stop_stream()
    assert lost > 0 and emu.dropped >= lost


@pytest.mark.parametrize(
    ("fault", "error"), [(Fault.GARBLE, FrameError), (Fault.TRUNCATE, FrameError), (Fault.CRC_ERROR, ChecksumError)]
)
def test_a_damaged_frame_is_a_typed_error_and_the_stream_goes_on(imu_rig, fault, error) -> None:
    _, emu, imu = imu_rig()
    imu.start_stream()
    imu.read_block()
    emu.inject(fault)
    t0 = time.monotonic()
    with pytest.raises(error):
        for _ in range(200):
            imu.read_block()
    assert time.monotonic() - t0 < 2.0
    errors = 0
    for _ in range(3):  # the resynchronised stream carries on
        try:
            assert len(imu.read_block()) > 0
        except DriverError:  # the bad frame's seq shows up as one lost sample, or the tail of the damage
            errors += 1
    assert errors <= 1


def test_silence_becomes_a_timeout(imu_rig) -> None:
    _, emu, imu = imu_rig(silence_s=0.4)
    imu.start_stream()
    imu.read_block()
    emu.inject(Fault.NO_ANSWER, count=None)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="silent"):
        for _ in range(500):
            imu.read_block()
    assert time.monotonic() - t0 < 0.4 + 1.0


def test_no_answer_to_a_command_times_out_after_its_retries(imu_rig) -> None:
    _, emu, imu = imu_rig()
    emu.inject(Fault.NO_ANSWER, count=None)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="after 3 attempts"):
        imu.query_info()
    assert time.monotonic() - t0 < 3 * 0.3 + 0.5


def test_disconnect_and_sensor_fault(imu_rig) -> None:
    _, emu, imu = imu_rig()
    imu.start_stream()
    imu.read_block()
    emu.sensor_fault(0b001)
    with pytest.raises(DeviceFault, match="gyro fault") as info:
        for _ in range(200):
            imu.read_block()
    assert info.value.field == "status"
    emu.sensor_fault(0)
    # Samples made before the clear may still be on the line with the bit set (on a pty, more of them on a
    # busy machine): the fault has cleared once a block arrives without it.
    for _ in range(200):
        with contextlib.suppress(DeviceFault):
            imu.read_block()
            break
    else:
        pytest.fail("the gyro fault did not clear within 200 blocks")
    emu.inject(Fault.DISCONNECT)
    t0 = time.monotonic()
    with pytest.raises(Disconnected):
        for _ in range(500):
            imu.read_block()
    assert time.monotonic() - t0 < 2.0


def test_rates_and_remounting_are_refused_with_what_is_allowed(imu_rig) -> None:
    world, _, _ = imu_rig()
    with pytest.raises(LimitError, match=r"rate_hz = 300.*200, 400, 500, 1000"):
        StrapdownImu("/dev/null", rate_hz=300)
    with pytest.raises(DriverError, match=r"fixture_pose = 12.*allowed 1, 2"):
        world.operator.perform("mount", {"fixture_pose": 12})
    world.shared("shaker", ShakerMotion).start(sine_drive(20.0, 1.0, 9.80665), world.clock.now_s(), 1.0)
    with pytest.raises(DriverError, match="while the shaker runs"):
        world.operator.perform("mount", {"fixture_pose": 3})
