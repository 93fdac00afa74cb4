"""Grating read head: frame codecs, then the real driver against its emulator over a pty and a sim:// line.

The world-dependent tests use drivers.world.SimStation with the table
vibrating, so positions are checked against world.table_position_m at the
samples' own time stamps (exact to the 1 nm quantisation).
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import (
    ChecksumError,
    DeviceFault,
    DeviceTimeout,
    Disconnected,
    DriverError,
    FrameError,
    LimitError,
)
from drivers.grating import driver as grating_driver
from drivers.grating import protocol as g
from drivers.grating.driver import GratingReadHead
from drivers.pty_link import Fault
from drivers.serial_port import SYNC, Frame, FrameParser, crc16, encode_frame

pytestmark = pytest.mark.timeout(60)


# ---------------------------------------------------------------- CRCs


def test_crc16_is_ccitt_false() -> None:
    assert crc16(b"123456789") == 0x29B1


def _crc6_long_division(data: int, n_bits: int) -> int:
    """Independent reference: remainder of data * x^6 by x^6 + x + 1, inverted."""
    rem = data << 6
    for bit in range(n_bits + 5, 5, -1):
        if rem >> bit & 1:
            rem ^= 0x43 << (bit - 6)
    return ~rem & 0x3F


def test_biss_crc6_matches_long_division() -> None:
    rng = np.random.default_rng(1)
    for data in [0, 1, 2**38 - 1, *rng.integers(0, 2**38, 200).tolist()]:
        assert g.biss_crc6(int(data)) == _crc6_long_division(int(data), 38)
    assert g.CRC6_TABLE[:8] == [0x00, 0x0C, 0x18, 0x14, 0x30, 0x3C, 0x28, 0x24]


@pytest.mark.parametrize("pos", [0, 1, -1, 123_456_789, -(2**35), 2**35 - 1])
def test_biss_word_roundtrip(pos: int) -> None:
    for n_e, n_w in [(1, 1), (0, 1), (1, 0)]:
        got = g.decode_biss(g.biss_word(pos, n_e, n_w))
        assert got == (pos, not n_e, not n_w, True)


def test_biss_crc6_catches_every_single_bit_error() -> None:
    word = g.biss_word(-987_654_321)
    for bit in range(44):
        assert not g.decode_biss(word ^ (1 << bit))[3]


def test_vectorised_biss_words_match_scalar() -> None:
    rng = np.random.default_rng(2)
    pos = rng.integers(-(2**35), 2**35, 500)
    n_e = rng.integers(0, 2, 500).astype(np.uint8)
    n_w = rng.integers(0, 2, 500).astype(np.uint8)
    words = g.biss_words_np(pos, n_e, n_w)
    for p, e, w, word in zip(pos, n_e, n_w, words, strict=True):
        assert int(word) == g.biss_word(int(p), int(e), int(w))


def test_position_out_of_range_is_refused() -> None:
    with pytest.raises(ValueError):
        g.biss_word(2**35)


# ---------------------------------------------------------------- frame parser


def _frames(n: int) -> list[bytes]:
    return [encode_frame(0x10, bytes([i]) * 5) for i in range(n)]


def _drain(p: FrameParser) -> list[Frame | DriverError]:
    out: list[Frame | DriverError] = []
    while (item := p.next_item()) is not None:
        out.append(item)
    return out


def _bulk_then_one_by_one(p: FrameParser, payload_size: int) -> list[Frame | DriverError]:
    """What the grating driver reads: runs of well-formed frames in bulk (peek_run), the rest by next_item."""
    out: list[Frame | DriverError] = []
    while True:
        run = p.peek_run(0x10, payload_size, max_frames=3)  # short runs: every boundary gets crossed
        if len(run):
            out += [Frame(0x10, row.tobytes()) for row in run[:2]]
            p.consume_run(min(len(run), 2), payload_size)  # take part of what was peeked, as at max_samples
            continue
        item = p.next_item()
        if item is None:
            return out
        out.append(item)


def _as_compared(items: list[Frame | DriverError]) -> list[object]:
    return [(i.type, i.payload) if isinstance(i, Frame) else (type(i).__name__, str(i)) for i in items]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(["good", "good", "good", "crc", "cut", "garbage", "other", "long"]), max_size=40),
       st.integers(1, 64))  # fmt: skip
def test_bulk_parsing_gives_what_frame_by_frame_parsing_gives(kinds: list[str], chunk: int) -> None:
    """FrameParser.peek_run / consume_run hand out exactly the frames next_item would, in the same order, and
    leave every bad stretch (bad CRC, cut frame, garbage, another type or length) to next_item's errors."""
    stream = b""
    for i, kind in enumerate(kinds):
        frame = encode_frame(0x10, bytes([i % 256]) * 12)
        if kind == "crc":
            frame = frame[:-1] + bytes([frame[-1] ^ 0x01])
        elif kind == "cut":
            frame = frame[:-4]
        elif kind == "garbage":
            frame = bytes([0x11, 0x22, 0xA5])
        elif kind == "other":
            frame = encode_frame(0x83, bytes([i % 256]) * 12)
        elif kind == "long":
            frame = encode_frame(0x10, bytes([i % 256]) * 13)
        stream += frame
    one_by_one, bulk = FrameParser("t"), FrameParser("t")
    expected: list[Frame | DriverError] = []
    got: list[Frame | DriverError] = []
    for k in range(0, len(stream), chunk):  # bytes arrive in pieces, as from the line
        one_by_one.feed(stream[k : k + chunk])
        bulk.feed(stream[k : k + chunk])
        expected += _drain(one_by_one)
        got += _bulk_then_one_by_one(bulk, 12)
    assert _as_compared(got) == _as_compared(expected)
    assert (bulk.crc_errors, bulk.frame_errors, bulk.skipped_bytes) == (
        one_by_one.crc_errors, one_by_one.frame_errors, one_by_one.skipped_bytes)  # fmt: skip


def test_parser_roundtrip_byte_by_byte() -> None:
    p = FrameParser("t")
    out: list[Frame | DriverError] = []
    for byte in b"".join(_frames(20)):
        p.feed(bytes([byte]))
        out += _drain(p)
    assert [f.payload[0] for f in out if isinstance(f, Frame)] == list(range(20))
    assert len(out) == 20


def test_parser_joins_mid_stream_silently() -> None:
    p = FrameParser("t")
    p.feed(b"".join(_frames(3))[7:] + b"".join(_frames(2)))
    out = _drain(p)
    assert all(isinstance(f, Frame) for f in out)
    assert [f.payload[0] for f in out] == [1, 2, 0, 1]


def test_parser_reports_garbage_once_and_resyncs() -> None:
    f = _frames(4)
    p = FrameParser("t")
    p.feed(f[0] + b"\x00\x11\xa5\x22" * 10 + f[1] + f[2])
    out = _drain(p)
    kinds = [type(x) for x in out]
    assert kinds == [Frame, FrameError, Frame, Frame]
    assert p.skipped_bytes == 40


def test_parser_tells_crc_error_from_truncation() -> None:
    f = _frames(4)
    bad_crc = f[1][:-1] + bytes([f[1][-1] ^ 1])
    p = FrameParser("t")
    p.feed(f[0] + bad_crc + f[2] + f[3][: len(f[3]) // 2] + f[0] + f[2])
    out = _drain(p)
    assert [type(x) for x in out] == [Frame, ChecksumError, Frame, FrameError, Frame, Frame]
    assert [x.payload[0] for x in out if isinstance(x, Frame)] == [0, 2, 0, 2]


def test_parser_rejects_impossible_length() -> None:
    p = FrameParser("t", max_payload=64)
    p.feed(_frames(1)[0] + SYNC + b"\x10\xff\xff" + _frames(2)[1])
    out = _drain(p)
    assert [type(x) for x in out] == [Frame, FrameError, Frame]


def test_sample_frame_layout() -> None:
    payload = g.SAMPLE_PAYLOAD.pack(7, 123_456, g.biss_word(-5).to_bytes(6, "big"))
    frame = encode_frame(g.SAMPLE, payload)
    assert len(frame) == 19 and frame[:2] == SYNC and frame[2] == g.SAMPLE
    assert int.from_bytes(frame[3:5], "little") == 12
    assert int.from_bytes(frame[-2:], "little") == crc16(frame[2:-2])


# ---------------------------------------------------------------- driver against emulator


@pytest.fixture(params=["bulk", "one_by_one"])
def parsing(request, monkeypatch) -> str:
    """The driver's two ways through the stream (in bulk from one frame on, or never in bulk): every test
    that takes it must pass both ways, faults included."""
    monkeypatch.setattr(grating_driver, "BULK_MIN_FRAMES", 1 if request.param == "bulk" else 1 << 62)
    return request.param


def test_streams_world_positions_without_loss(grating_rig, parsing) -> None:
    world, _, head = grating_rig
    head.start_streaming()
    block = head.read_for(2000, timeout_s=2.0)
    assert block.lost == 0
    assert np.all(np.diff(block.seq) == 1)
    ticks = np.rint(block.t_s / 50e-9).astype(np.int64)
    assert np.all(np.diff(ticks) == g.TICKS_PER_CYCLE)
    assert np.all(ticks % g.TICKS_PER_CYCLE == 0)  # the board's 5 kHz grid
    z_true = np.asarray(world.table_position_m(block.t_s))
    assert np.max(np.abs(block.z_m - z_true)) <= 0.5e-9 + 1e-15
    assert np.ptp(block.z_m) > 1e-3  # the table is really moving
    head.stop_streaming()
    assert not head.status()["streaming"]


def test_status_query_mid_stream_loses_nothing(grating_rig) -> None:
    _, _, head = grating_rig
    head.start_streaming()
    first = head.read_for(200)
    st = head.status()
    assert st["streaming"] and st["divider"] == 1 and not st["error"]
    rest = head.read_for(1000)
    assert rest.lost == 0 and rest.seq[0] == first.seq[-1] + 1


def test_divider_lowers_the_rate(grating_rig) -> None:
    _, _, head = grating_rig
    head.start_streaming(divider=50)
    block = head.read_for(20, timeout_s=1.0)
    assert head.rate_hz == 100.0
    assert np.allclose(np.diff(block.t_s), 0.01, atol=1e-12)
    with pytest.raises(LimitError, match="divider"):
        head.start_streaming(divider=0)


def test_samples_iterator(grating_rig) -> None:
    _, _, head = grating_rig
    head.start_streaming()
    it = head.samples()
    s = [next(it) for _ in range(50)]
    assert [x.seq for x in s] == list(range(s[0].seq, s[0].seq + 50))
    assert not any(x.warning for x in s)


def test_session_of_streaming_loses_no_sample(grating_rig, parsing) -> None:
    """40 000 frames (8 s at 5 kHz) through the line: every seq and time stamp present."""
    _, emu, head = grating_rig
    head.start_streaming()
    n = 40_000
    block = head.read_for(n, timeout_s=2.0)
    assert len(block) == n
    assert block.lost == 0 and head.stats.lost_samples == 0 and emu.dropped == 0
    assert np.array_equal(block.seq, np.arange(block.seq[0], block.seq[0] + n))
    ticks = np.rint(block.t_s / 50e-9).astype(np.int64)
    assert np.all(np.diff(ticks) == g.TICKS_PER_CYCLE)
    assert head.crc_errors == 0 and head.frame_errors == 0


@pytest.mark.parametrize("transport", ["pty"])  # a sim:// line paces in station time: 10x is not too fast there
def test_virtual_clock_faster_than_the_line_shows_gaps(grating_rig_at) -> None:
    """At 10x real time, 50 000 samples/s cannot fit through 3 Mbaud: the board drops,
    the driver counts exactly those gaps and every received stamp is on the 5 kHz grid."""
    _, emu, head = grating_rig_at(speed=10.0)
    head.start_streaming()
    block = head.read_for(30_000, timeout_s=2.0)
    steps = np.diff(block.seq)
    assert block.lost > 0 and np.all(steps >= 1)
    assert int(np.sum(steps - 1)) == block.lost
    ticks = np.rint(block.t_s / 50e-9).astype(np.int64)
    assert np.array_equal(np.diff(ticks), steps * g.TICKS_PER_CYCLE)
    assert head.stats.lost_samples <= emu.dropped


def test_rate_divider_keeps_up_with_a_fast_virtual_clock(grating_rig_at) -> None:
    _, emu, head = grating_rig_at(speed=10.0)
    head.start_streaming(divider=10)  # 500 Hz of station time, 5000 frames per wall second
    block = head.read_for(10_000, timeout_s=2.0)
    assert block.lost == 0 and emu.dropped == 0
    assert np.all(np.diff(block.seq) == 1)


# ---------------------------------------------------------------- faults


def _read_until_error(head: GratingReadHead, within: int = 2 * 5000) -> DriverError:
    """The first error within `within` samples (2 s of the 5 kHz stream: an injected fault takes the first
    frame the board sends next, at the latest a sim:// line's stream batch of 0.05 s later)."""
    got = 0
    while got < within:
        try:
            got += len(head.read_block(timeout_s=1.0))
        except DriverError as exc:
            return exc
    raise AssertionError(f"no error raised within {got} samples")


@pytest.mark.parametrize(
    ("fault", "error"),
    [(Fault.CRC_ERROR, ChecksumError), (Fault.GARBLE, FrameError), (Fault.TRUNCATE, FrameError)],
)
def test_damaged_frame_raises_then_stream_continues(grating_rig, parsing, fault, error) -> None:
    _, emu, head = grating_rig
    head.start_streaming()
    head.read_for(100)
    emu.inject(fault)
    exc = _read_until_error(head)
    assert type(exc) is error
    after = head.read_for(500)
    assert after.lost == 1  # exactly the damaged sample, counted at the next good one
    assert head.stats.lost_samples == 1
    assert np.all(np.diff(after.seq) == 1)


def test_signal_loss_raises_device_fault_until_it_clears(grating_rig, parsing) -> None:
    _, emu, head = grating_rig
    head.start_streaming()
    head.read_for(100)
    emu.inject(Fault.SIGNAL_LOSS, count=None)
    exc = _read_until_error(head)
    assert isinstance(exc, DeviceFault) and exc.field == "nE"
    assert "signal lost" in str(exc)
    with pytest.raises(DeviceFault, match="signal lost"):  # bounded, not a hang
        head.read_block(timeout_s=0.3)
    emu.clear_fault(Fault.SIGNAL_LOSS)
    block = head.read_for(100)
    assert len(block) == 100 and head.stats.invalid_samples > 0
    assert head.stats.lost_samples == 0  # invalid samples are not lost samples


def test_no_answer_to_start_is_retried_then_times_out(grating_rig) -> None:
    _, emu, head = grating_rig
    emu.inject(Fault.NO_ANSWER, count=1)
    head.start_streaming()  # first attempt unanswered, the retry succeeds
    assert head.streaming
    head.stop_streaming()
    emu.inject(Fault.NO_ANSWER, count=None)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match=r"after 3 attempts"):
        head.start_streaming()
    assert time.monotonic() - t0 < 3 * head.timeout_s + 0.5


def test_silent_stream_times_out(grating_rig) -> None:
    _, emu, head = grating_rig
    head.start_streaming()
    head.read_for(50)
    emu.inject(Fault.NO_ANSWER, count=None)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="no sample"):  # once the samples sent before it are read
        while time.monotonic() - t0 < 2.0:
            head.read_block(timeout_s=0.3)
    assert time.monotonic() - t0 < 2.0


def test_disconnect_mid_stream(grating_rig) -> None:
    _, emu, head = grating_rig
    head.start_streaming()
    head.read_for(100)
    emu.inject(Fault.DISCONNECT)
    t0 = time.monotonic()
    with pytest.raises(Disconnected):
        for _ in range(1000):
            head.read_block(timeout_s=1.0)
    assert time.monotonic() - t0 < 2.0
    head.close()  # closing after a disconnect never raises


def test_port_is_exclusive_and_missing_port_is_disconnected(grating_rig) -> None:
    _, emu, _ = grating_rig
    with pytest.raises(DriverError, match="in use"):
        GratingReadHead(emu.port).open()
    missing = f"/dev/pts/does-not-exist-{os.getpid()}"
    with pytest.raises(Disconnected):
        GratingReadHead(missing).open()
