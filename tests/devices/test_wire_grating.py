"""Grating read head's interface board: known-answer frames from drivers.grating.driver's docstring.

Framing as for every binary board (sync A5 5A, type, u16 length LE, payload, CRC-16/CCITT-FALSE LE).
SAMPLE payload: u16 seq, u32 ticks (50 ns), 6-byte BiSS-C word big-endian: bits 43..8 the position,
36-bit two's complement in nm, bit 7 nE, bit 6 nW (both active low), bits 5..0 the CRC-6 (poly 0x43,
init 0, inverted) of the 38 bits above it. The CRCs below were worked out by long division from those
definitions, outside the code under test: +1 000 000 nm with nE = nW = 1 is 00 00 0f 42 40 c7.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from wire import FrozenClock, answers, scripted_port

from drivers.errors import ChecksumError, DeviceFault
from drivers.grating import protocol
from drivers.grating.driver import GratingReadHead
from drivers.grating.emulator import GratingEmulator

H = bytes.fromhex
START_1 = H("a5 5a 01 02 00 01 00 04 65")  # divider 1: every 5 kHz cycle
START_0 = H("a5 5a 01 02 00 00 00 35 56")
ACK_START_OK = H("a5 5a 81 02 00 01 00 d4 47")
ACK_START_REJECTED = H("a5 5a 81 02 00 01 01 f5 57")
STOP = H("a5 5a 02 00 00 fc a2")
ACK_STOP_OK = H("a5 5a 81 02 00 02 00 87 12")
STATUS_Q = H("a5 5a 03 00 00 cc 95")
STATUS_IDLE_1S = H("a5 5a 83 08 00 00 01 00 00 2d 31 01 03 7a 28")  # not streaming, divider 1, 1.0 s, nE nW = 1
STATUS_STREAMING_WARNING = H(
    "a5 5a 83 08 00 01 05 00 04 03 02 01 02 a9 3e"
)  # divider 5, flags 2: nE = 0 (error), nW = 1
UNKNOWN_7F = H("a5 5a 7f 00 00 a5 38")
ACK_7F_REJECTED = H("a5 5a 81 02 00 7f 01 a3 7c")
# samples seq 0, 1, 2 at 1.0 s + k 0.2 ms, positions 1 000 000, 1 000 010, 1 000 020 nm
SAMPLES = [
    H("a5 5a 10 0c 00 00 00 00 2d 31 01 00 00 0f 42 40 c7 62 55"),
    H("a5 5a 10 0c 00 01 00 a0 3c 31 01 00 00 0f 42 4a fc 00 5b"),
    H("a5 5a 10 0c 00 02 00 40 4c 31 01 00 00 0f 42 54 f2 d5 9b"),
]
SAMPLE_1_SIGNAL_LOST = H("a5 5a 10 0c 00 01 00 a0 3c 31 01 00 00 00 00 00 7c ac 8f")  # nE = 0, position 0
# what the emulator streams after START at 1.0 s on a table standing at +1 mm: k = 5001, 5002
EMULATED_SAMPLES = H(
    "a5 5a 10 0c 00 00 00 a0 3c 31 01 00 00 0f 42 40 c7 86 30 a5 5a 10 0c 00 01 00 40 4c 31 01 00 00 0f 42 40 c7 0b 37"
)
# sample 1 with its CRC-6 changed from 0x3c to 0x03 (and a good CRC-16 over the damaged payload)
SAMPLE_1_BAD_BISS_CRC = H("a5 5a 10 0c 00 01 00 a0 3c 31 01 00 00 0f 42 4a c3 bc 9c")
TICK_S = 50e-9


def _head(port: str) -> GratingReadHead:
    return GratingReadHead(port, timeout_s=0.3, clock=FrozenClock(1.0))


def test_biss_word_known_answers() -> None:
    assert protocol.biss_word(1_000_000).to_bytes(6, "big") == H("00 00 0f 42 40 c7")
    assert protocol.biss_word(-5).to_bytes(6, "big") == H("0f ff ff ff fb d5")
    # nW = 0 (a warning, active low): decode_biss reports error and warning active-high
    assert protocol.decode_biss(int.from_bytes(H("00 00 0f 42 40 84"), "big")) == (1_000_000, False, True, True)


def test_start_stream_and_samples() -> None:
    with scripted_port([(START_1, ACK_START_OK + b"".join(SAMPLES))]) as port, _head(port).open() as head:
        head.start_streaming(1)
        block = head.read_for(3)
        head.streaming = False  # the transcript has no STOP for close() to send
    np.testing.assert_array_equal(block.seq, [0, 1, 2])
    np.testing.assert_allclose(block.t_s, [1.0, 1.0002, 1.0004], atol=TICK_S)
    np.testing.assert_allclose(block.z_m, [1.0e-3, 1.00001e-3, 1.00002e-3], atol=1e-12)
    assert block.lost == 0 and not block.warning.any()


def test_a_gap_in_seq_and_stamps_counts_lost_samples() -> None:
    with scripted_port([(START_1, ACK_START_OK + SAMPLES[0] + SAMPLES[2])]) as port, _head(port).open() as head:
        head.start_streaming(1)
        block = head.read_for(2)
        head.streaming = False
    assert block.lost == 1 and list(block.seq) == [0, 2]


def test_start_rejected_is_a_device_fault() -> None:
    with (
        scripted_port([(START_1, ACK_START_REJECTED)]) as port,
        _head(port).open() as head,
        pytest.raises(DeviceFault, match="rejected"),
    ):
        head.start_streaming(1)


def test_stop_and_status() -> None:
    transcript = [(STOP, ACK_STOP_OK), (STATUS_Q, STATUS_STREAMING_WARNING)]
    with scripted_port(transcript) as port, _head(port).open() as head:
        head.stop_streaming()
        assert head.status() == {"streaming": True, "divider": 5, "ticks": 0x01020304, "error": True, "warning": False}


def test_a_sample_with_a_bad_biss_crc_is_dropped_with_a_checksum_error() -> None:
    frames = SAMPLES[0] + SAMPLE_1_BAD_BISS_CRC + SAMPLES[2]
    with scripted_port([(START_1, ACK_START_OK + frames)]) as port, _head(port).open() as head:
        head.start_streaming(1)
        first = head.read_block(max_samples=3)
        with pytest.raises(ChecksumError, match="BiSS CRC-6"):
            head.read_block()
        rest = head.read_block()
        head.streaming = False
    assert list(first.seq) + list(rest.seq) == [0, 2]


def test_a_frame_with_a_bad_crc16_is_a_checksum_error() -> None:
    damaged = SAMPLES[1][:-1] + bytes([SAMPLES[1][-1] ^ 0xFF])
    with scripted_port([(START_1, ACK_START_OK + SAMPLES[0] + damaged + SAMPLES[2])]) as port, _head(port).open() as h:
        h.start_streaming(1)
        h.read_block(max_samples=1)
        with pytest.raises(ChecksumError):
            h.read_block()
        h.streaming = False


def test_signal_loss_bit_is_a_device_fault() -> None:
    with scripted_port([(START_1, ACK_START_OK + SAMPLES[0] + SAMPLE_1_SIGNAL_LOST)]) as port, _head(port).open() as h:
        h.start_streaming(1)
        assert list(h.read_block(max_samples=1).seq) == [0]
        with pytest.raises(DeviceFault) as info:
            h.read_block()
        h.streaming = False
    assert info.value.field == "nE"


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> GratingEmulator:
    world = SimpleNamespace(clock=FrozenClock(1.0), table_position_m=lambda t_s: np.full(np.shape(t_s), 1e-3))
    return GratingEmulator(world)


def test_emulator_commands(emulator: GratingEmulator) -> None:
    assert answers(emulator, STATUS_Q) == STATUS_IDLE_1S
    assert answers(emulator, START_0) == ACK_START_REJECTED  # divider < 1
    assert answers(emulator, UNKNOWN_7F) == ACK_7F_REJECTED
    assert answers(emulator, START_1) == ACK_START_OK
    assert answers(emulator, STOP) == ACK_STOP_OK


def test_emulator_streams_samples_on_the_5khz_grid(emulator: GratingEmulator) -> None:
    assert answers(emulator, START_1) == ACK_START_OK
    assert answers(emulator, b"", poll_at_s=1.00045) == EMULATED_SAMPLES


def test_emulator_ignores_a_command_with_a_bad_crc(emulator: GratingEmulator) -> None:
    assert answers(emulator, STATUS_Q[:-1] + b"\x00" + STATUS_Q) == STATUS_IDLE_1S
