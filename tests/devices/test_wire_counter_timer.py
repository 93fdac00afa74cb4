"""Counter/timer board: known-answer frames from the protocol in drivers.counter_timer.driver's docstring.

Frame: sync A5 5A, type, u16 length (LE), payload, CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over
type .. payload, little-endian. Time stamps: u32 counts of 50 ns ticks (1.0 s = 20 000 000 = 0x01312D00).
The CRCs below were worked out from that definition, outside the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest
from wire import FrozenClock, answers, scripted_port

from drivers.counter_timer.driver import CounterTimer
from drivers.counter_timer.emulator import CounterEmulator
from drivers.errors import ChecksumError, DeviceFault, LimitError
from drivers.world import SimStation

H = bytes.fromhex
STATUS_Q = H("a5 5a 22 00 00 3a 24")
STATUS_ARMED = H("a5 5a a2 0a 00 01 e8 03 00 00 78 56 34 12 00 65 df")  # armed, P 1000, ticks 0x12345678
STATUS_IDLE_1S = H("a5 5a a2 0a 00 00 00 00 00 00 00 2d 31 01 00 2c e8")  # idle, P 0, ticks at 1.0 s
ARM_1000_EDGES = H("a5 5a 20 05 00 e8 03 00 00 01 2d 81")  # P 1000, flags 1 (stream every edge)
ARM_3 = H("a5 5a 20 05 00 03 00 00 00 00 23 dd")
ARM_0 = H("a5 5a 20 05 00 00 00 00 00 00 f1 33")
ACK_ARM_OK = H("a5 5a a0 02 00 20 00 e6 d0")
ACK_ARM_BUSY = H("a5 5a a0 02 00 20 01 c7 c0")
ACK_ARM_BAD = H("a5 5a a0 02 00 20 02 a4 f0")
ABORT = H("a5 5a 21 00 00 6a 7d")
ACK_ABORT_OK = H("a5 5a a0 02 00 21 00 d7 e3")
UNKNOWN_7F = H("a5 5a 7f 00 00 a5 38")
ACK_7F_BAD = H("a5 5a a0 02 00 7f 02 25 ee")
# a window of 3 pulses opened at 1.0 s, crossings at 1.1 and 1.6 s, closed at 1.5 s
OPEN_1S = H("a5 5a b0 04 00 00 2d 31 01 09 e7")
REF_0 = H("a5 5a b1 08 00 00 00 00 00 80 b1 4f 01 c4 29")
CLOSE_3 = H("a5 5a b3 08 00 80 c3 c9 01 03 00 00 00 1a 04")
REF_1 = H("a5 5a b1 08 00 01 00 00 00 00 48 e8 01 05 4a")
DONE_2_0 = H("a5 5a b4 08 00 02 00 00 00 00 00 00 00 48 36")
FAULT_OVERFLOW = H("a5 5a bf 05 00 01 00 36 6e 01 56 cf")  # code 1 at 1.2 s
TICK_S = 50e-9


def _board(port: str, clock: FrozenClock | None = None) -> CounterTimer:
    return CounterTimer(port, timeout_s=0.3, silence_s=0.5, clock=clock)


def _bad_crc(frame: bytes) -> bytes:
    return frame[:-1] + bytes([frame[-1] ^ 0xFF])


# ---------------------------------------------------------------- driver: bytes out, values in


def test_status_query_and_its_reply() -> None:
    with scripted_port([(STATUS_Q, STATUS_ARMED)]) as port, _board(port).open() as board:
        assert board.status() == {"state": "armed", "preset": 1000, "ticks": 0x12345678, "fault": None}


def test_arm_with_edge_streaming() -> None:
    with scripted_port([(ARM_1000_EDGES, ACK_ARM_OK)]) as port, _board(port).open() as board:
        board.arm(1000, stream_edges=True)


def test_arm_refused_busy_is_a_device_fault() -> None:
    with (
        scripted_port([(ARM_1000_EDGES, ACK_ARM_BUSY)]) as port,
        _board(port).open() as board,
        pytest.raises(DeviceFault, match="busy") as info,
    ):
        board.arm(1000, stream_edges=True)
    assert info.value.value == 1


def test_bad_preset_sends_nothing() -> None:
    with scripted_port([]) as port, _board(port).open() as board, pytest.raises(LimitError):
        board.arm(0)


def test_status_reply_with_a_bad_crc_is_dropped_and_the_query_asked_again() -> None:
    """STATUS? is retried (driver docstring): the damaged reply costs one more exchange."""
    transcript = [(STATUS_Q, _bad_crc(STATUS_ARMED)), (STATUS_Q, STATUS_ARMED)]
    with scripted_port(transcript) as port, _board(port).open() as board:
        assert board.status()["preset"] == 1000


def test_abort() -> None:
    with scripted_port([(ABORT, ACK_ABORT_OK)]) as port, _board(port).open() as board:
        board.abort()


def test_a_window_from_its_event_frames() -> None:
    """OPEN, REF 0, CLOSE, REF 1 (the closing crossing), DONE: Tm = 0.5 s, t1 = 0.1 s, Np = 1, t2 = 0.1 s."""
    clock = FrozenClock(1.0)
    events = OPEN_1S + REF_0 + CLOSE_3 + REF_1 + DONE_2_0
    with scripted_port([(ARM_3, ACK_ARM_OK + events)]) as port, _board(port, clock).open() as board:
        board.arm(3)
        w = board.wait_window(timeout_s=2.0)
    assert (w.preset, w.pulses) == (3, 3)
    assert w.open_s == pytest.approx(1.0, abs=TICK_S) and w.close_s == pytest.approx(1.5, abs=TICK_S)
    np.testing.assert_allclose(w.crossings_s, [1.1, 1.6], atol=TICK_S)
    assert w.Np == 1 and w.t1_s == pytest.approx(0.1, abs=TICK_S) and w.t2_s == pytest.approx(0.1, abs=TICK_S)


def test_fault_frame_aborts_the_window() -> None:
    clock = FrozenClock(1.0)
    with scripted_port([(ARM_3, ACK_ARM_OK + OPEN_1S + FAULT_OVERFLOW)]) as port, _board(port, clock).open() as board:
        board.arm(3)
        with pytest.raises(DeviceFault, match="counter overflow") as info:
            board.wait_window(timeout_s=2.0)
    assert info.value.field == "pulse_count"


def test_an_event_with_a_bad_crc_fails_the_open_window() -> None:
    """A CRC mismatch shows once the next sync arrives (drivers.serial_port framing): the window is not trusted."""
    clock = FrozenClock(1.0)
    events = OPEN_1S + _bad_crc(REF_0) + CLOSE_3
    with scripted_port([(ARM_3, ACK_ARM_OK + events)]) as port, _board(port, clock).open() as board:
        board.arm(3)
        with pytest.raises(ChecksumError, match="not trusted"):
            board.wait_window(timeout_s=2.0)


# ---------------------------------------------------------------- emulator: bytes in, bytes out


@pytest.fixture
def emulator() -> CounterEmulator:
    return CounterEmulator(SimStation(clock=FrozenClock(1.0)))


def test_emulator_status_reply(emulator: CounterEmulator) -> None:
    assert answers(emulator, STATUS_Q) == STATUS_IDLE_1S


def test_emulator_arm_abort_and_refusals(emulator: CounterEmulator) -> None:
    assert answers(emulator, ARM_0) == ACK_ARM_BAD  # preset < 1: bad argument
    assert answers(emulator, ARM_3) == ACK_ARM_OK
    assert answers(emulator, ARM_3) == ACK_ARM_BUSY  # a window is under way
    assert answers(emulator, ABORT) == ACK_ABORT_OK
    assert answers(emulator, UNKNOWN_7F) == ACK_7F_BAD


def test_emulator_ignores_a_command_with_a_bad_crc(emulator: CounterEmulator) -> None:
    assert answers(emulator, _bad_crc(STATUS_Q)) == b""
    assert answers(emulator, STATUS_Q) == STATUS_IDLE_1S  # and resynchronises on the next frame
