"""Strapdown IMU: known-answer frames from the protocol in drivers.imu.driver's docstring.

Framing as for every binary board (sync A5 5A, type, u16 length LE, payload, CRC-16/CCITT-FALSE LE), worked
out from those definitions outside the code under test. INFO: u16 rate, f64 gyro LSB (1e-9 rad), f64
accelerometer LSB (1e-7 m/s), u8 streaming, 16-byte serial. SAMPLE: u32 seq, u32 ticks (50 ns; 200 Hz is
100 000 ticks a sample), 3 x i32 angle and 3 x i32 velocity increments in LSB, u8 status.
"""

from __future__ import annotations

import binascii
import contextlib

import numpy as np
import pytest
from wire import FrozenClock, answers, driver_on, scripted_port

from drivers.errors import DeviceFault, FrameError
from drivers.imu.driver import ImuInfo, StrapdownImu
from drivers.imu.emulator import ImuEmulator
from drivers.world import SimStation

H = bytes.fromhex
STOP, ACK_STOP = H("a5 5a 41 00 00 01 e6"), H("a5 5a c0 02 00 41 00 21 f1")
RATE_200, RATE_400, RATE_300 = (
    H("a5 5a 43 02 00 c8 00 23 9c"),
    H("a5 5a 43 02 00 90 01 14 0b"),
    H("a5 5a 43 02 00 2c 01 74 50"),
)
ACK_RATE, ACK_RATE_BAD, ACK_RATE_BUSY = (H("a5 5a c0 02 00 43 00 43 97"), H("a5 5a c0 02 00 43 01 62 87"),
                                        H("a5 5a c0 02 00 43 02 01 b7"))  # fmt: skip
INFO_Q = H("a5 5a 42 00 00 51 bf")
INFO_200 = H(
    "a5 5a c2 23 00 c8 00 95 d6 26 e8 0b 2e 11 3e 48 af bc 9a f2 d7 7a 3e 00"
    " 53 49 4e 53 2d 52 4c 47 2d 30 30 30 32 00 00 00 dc d4"
)  # 200 Hz, 1e-9 rad, 1e-7 m/s, not streaming, "SINS-RLG-0002"
INFO_400 = INFO_200[:5] + H("90 01") + INFO_200[7:-2] + H("fc 1c")
START, ACK_START = H("a5 5a 40 00 00 31 d1"), H("a5 5a c0 02 00 40 00 10 c2")
OPENING = [(STOP, ACK_STOP), (RATE_200, ACK_RATE), (INFO_Q, INFO_200)]  # what open() says to the IMU
# seq 0 at 1.0 s: dtheta (1000, -2000, 3), dv (100, 0, -98066); seq 1 at 1.005 s: (1001, -2001, 4), (101, 1, -98065)
S0 = H(
    "a5 5a 50 21 00 00 00 00 00 00 2d 31 01 e8 03 00 00 30 f8 ff ff 03 00 00 00 64 00 00 00 00 00 00 00"
    " ee 80 fe ff 00 60 03"
)
S1 = H(
    "a5 5a 50 21 00 01 00 00 00 a0 b3 32 01 e9 03 00 00 2f f8 ff ff 04 00 00 00 65 00 00 00 01 00 00 00"
    " ef 80 fe ff 00 0e 57"
)
S1_GYRO_FAULT = S1[:-3] + H("01 2f 47")  # status bit 0
S2_STAMPED_AS_1 = S1[:5] + H("02") + S1[6:-2] + H("4b d1")  # seq 2 with seq 1's time stamp
TICK_S = 50e-9


def _imu_on(transcript: list[tuple[bytes, bytes]]) -> contextlib.AbstractContextManager[StrapdownImu]:
    """The driver opened on a port that plays its opening, `transcript`, then the STOP it sends as it closes."""
    return driver_on([*OPENING, *transcript, (STOP, ACK_STOP)],
                     lambda port: StrapdownImu(port, rate_hz=200, timeout_s=0.3, clock=FrozenClock(1.0)))  # fmt: skip


def test_open_sets_the_rate_and_reads_the_scale_factors() -> None:
    with scripted_port(OPENING) as port, StrapdownImu(port, rate_hz=200, timeout_s=0.3) as imu:
        assert imu.info == ImuInfo(200, 1e-9, 1e-7, False, "SINS-RLG-0002")


def test_an_imu_at_another_rate_is_a_device_fault() -> None:
    opening = [(STOP, ACK_STOP), (RATE_200, ACK_RATE), (INFO_Q, INFO_400)]
    with scripted_port(opening) as port, pytest.raises(DeviceFault, match="another rate"):
        StrapdownImu(port, rate_hz=200, timeout_s=0.3).open()


def test_a_stream_of_increments() -> None:
    with _imu_on([(START, ACK_START + S0 + S1)]) as imu:
        imu.start_stream()
        blocks = [imu.read_block()]
        while sum(map(len, blocks)) < 2:
            blocks.append(imu.read_block())
    seq, t_s = np.concatenate([b.seq for b in blocks]), np.concatenate([b.t_s for b in blocks])
    dtheta, dv = np.vstack([b.dtheta_rad for b in blocks]), np.vstack([b.dv_mps for b in blocks])
    np.testing.assert_array_equal(seq, [0, 1])
    np.testing.assert_allclose(t_s, [1.0, 1.005], atol=TICK_S)
    np.testing.assert_allclose(dtheta, [[1e-6, -2e-6, 3e-9], [1.001e-6, -2.001e-6, 4e-9]], rtol=1e-12)
    np.testing.assert_allclose(dv, [[1e-5, 0.0, -9.8066e-3], [1.01e-5, 1e-7, -9.8065e-3]], rtol=1e-12)


def test_status_bits_are_a_device_fault() -> None:
    with _imu_on([(START, ACK_START + S1_GYRO_FAULT)]) as imu:
        imu.start_stream()
        with pytest.raises(DeviceFault, match="gyro fault") as info:
            imu.read_block()
    assert (info.value.field, info.value.value) == ("status", 1)


def test_a_status_fault_comes_after_the_good_samples_before_it() -> None:
    """S0 and a faulted S1 arrive in one read: S0 is a finished measurement and is returned, the fault follows."""
    with _imu_on([(START, ACK_START + S0 + S1_GYRO_FAULT)]) as imu:
        imu.start_stream()
        assert list(imu.read_block().seq) == [0]
        with pytest.raises(DeviceFault, match="gyro fault in sample 1"):
            imu.read_block()


def test_a_seq_that_disagrees_with_its_stamp_is_a_frame_error() -> None:
    with _imu_on([(START, ACK_START + S1 + S2_STAMPED_AS_1)]) as imu:
        imu.start_stream()
        with pytest.raises(FrameError, match="disagrees with its time stamp"):
            while True:
                imu.read_block()


def test_a_sample_with_a_bad_crc_is_a_checksum_error_after_the_good_ones() -> None:
    damaged = S1[:-1] + bytes([S1[-1] ^ 0xFF])
    with _imu_on([(START, ACK_START + S0 + damaged + S0)]) as imu:
        imu.start_stream()
        assert list(imu.read_block().seq) == [0]
        with pytest.raises(FrameError):  # a ChecksumError is a FrameError
            imu.read_block()


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> ImuEmulator:
    return ImuEmulator(SimStation(clock=FrozenClock(1.0)))


def test_emulator_commands(emulator: ImuEmulator) -> None:
    assert answers(emulator, INFO_Q) == INFO_200
    assert answers(emulator, RATE_300) == ACK_RATE_BAD
    assert answers(emulator, RATE_400) == ACK_RATE
    assert answers(emulator, INFO_Q) == INFO_400
    assert answers(emulator, RATE_200) == ACK_RATE
    assert answers(emulator, START) == ACK_START
    assert answers(emulator, RATE_400) == ACK_RATE_BUSY  # not while streaming
    assert answers(emulator, STOP) == ACK_STOP


def test_emulator_sample_frames(emulator: ImuEmulator) -> None:
    """After START at 1.0 s at 200 Hz: samples k = 201, 202 (ticks k 100 000), seq from 0, each with a good CRC."""
    assert answers(emulator, START) == ACK_START
    out = answers(emulator, b"", poll_at_s=1.0101)
    frames = [out[i : i + 40] for i in range(0, len(out), 40)]
    assert [f[:13] for f in frames] == [
        H("a5 5a 50 21 00 00 00 00 00 a0 b3 32 01"),
        H("a5 5a 50 21 00 01 00 00 00 40 3a 34 01"),
    ]
    for f in frames:
        assert int.from_bytes(f[-2:], "little") == binascii.crc_hqx(f[2:-2], 0xFFFF)
        assert f[-3] == 0  # status: no fault
