"""Absolute grating read head (RELA/RESOLUTE-like, BiSS-C behind an interface board).

The interface board clocks the encoder at 5 kHz, latches each position with
its 50 ns timebase and streams the samples over a serial line (default
3 Mbaud, as FTDI-based boards run) in the shared binary framing of
`drivers.serial_port` (sync A5 5A, type, u16 length, payload, CRC-16/CCITT).

Host -> board
    0x01 START    u16 divider (output every divider-th 5 kHz cycle, >= 1)
    0x02 STOP     (empty)
    0x03 STATUS?  (empty)
Board -> host
    0x81 ACK      u8 command type, u8 result (0 OK, 1 rejected)
    0x83 STATUS   u8 streaming, u16 divider, u32 ticks, u8 BiSS flags (bit0 nE, bit1 nW)
    0x10 SAMPLE   u16 seq, u32 ticks, 6-byte BiSS word (big-endian, MSB first):

        bits 47..44  zero
        bits 43..8   position, 36-bit two's complement, 1 nm per count
        bit  7       nE  error, active low (0: position invalid, e.g. signal lost)
        bit  6       nW  warning, active low (0: e.g. scale dirty)
        bits 5..0    BiSS CRC-6 over position, nE, nW: polynomial 0x43
                     (x^6 + x + 1), init 0, transmitted inverted

seq counts output samples (wrapping at 2^16, restarting at 0 on START);
ticks is the 32-bit 50 ns time stamp of the position latch (wraps every
214.7 s). The driver unwraps both: a lost sample shows as a step of more than
one output period in the time stamps, cross-checked against seq mod 2^16.
The sample ACK'ing START precedes the first sample of the new stream.

Errors: no frame within `timeout_s` -> DeviceTimeout; bad frame CRC or BiSS
CRC-6 -> ChecksumError; truncated or garbled frame -> FrameError (the driver
resynchronises and streaming continues); nE = 0 -> DeviceFault (field "nE",
signal lost; those samples are dropped, not counted as lost); port gone ->
Disconnected. START/STOP/STATUS are idempotent, so they are retried.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from drivers.errors import (
    ChecksumError,
    DeviceFault,
    DeviceTimeout,
    DriverError,
    FrameError,
    LimitError,
)
from drivers.grating.protocol import (
    ACK,
    ACK_PAYLOAD,
    BASE_RATE_HZ,
    DEVICE,
    NM_PER_COUNT,
    SAMPLE,
    SAMPLE_FRAME_LEN,
    SAMPLE_PAYLOAD,
    START,
    START_PAYLOAD,
    STATUS,
    STATUS_PAYLOAD,
    STATUS_Q,
    STOP,
    TICKS_PER_CYCLE,
    decode_biss,
    decode_biss_np,
    sample_fields,
)
from drivers.serial_port import TICK_S, Frame, FramedDevice, TickUnwrapper
from station.clock import Clock

# ---------------------------------------------------------------- samples


@dataclass(frozen=True, slots=True)
class GratingSample:
    seq: int  # unwrapped sequence number since START
    t_s: float  # latch time on the device time base (station time when synchronised)
    z_m: float  # absolute table position
    warning: bool  # BiSS nW was active


@dataclass(frozen=True)
class SampleBlock:
    """A run of samples; `lost` samples went missing before or among them."""

    seq: np.ndarray  # int64
    t_s: np.ndarray
    z_m: np.ndarray
    warning: np.ndarray  # bool
    lost: int

    def __len__(self) -> int:
        return len(self.seq)


@dataclass
class GratingStats:
    samples: int = 0
    lost_samples: int = 0  # missing from the stream (gaps in seq/time stamps)
    invalid_samples: int = 0  # nE active (signal lost)
    warnings: int = 0  # nW active
    biss_crc_errors: int = 0


# Below this many buffered sample frames, parsing them one by one costs less than in bulk, numpy's cost per call
# (bench/bench_grating_decode.py: in bulk 9.4 against 4.3 us a frame at 20, 5.0 against 4.6 at 40, 2.1 against 4.3
# at 100, 0.5 against 4.2 at 1000).
BULK_MIN_FRAMES = 50


class GratingReadHead(FramedDevice):
    """Driver of the absolute grating read head's interface board.

    `clock`: if given, the board's time base is taken to be the station
    clock's (true for the emulator), so time stamps come out in station
    seconds; otherwise they count from the board's counter zero.
    """

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 3_000_000,
        timeout_s: float = 0.5,
        retries: int = 2,
        clock: Clock | None = None,
        max_divider: int = 5000,
    ) -> None:
        super().__init__(port, baud, clock=clock)
        self.timeout_s = timeout_s
        self.retries = retries
        self.max_divider = max_divider
        self._clock = clock
        self._unwrap = TickUnwrapper(clock, absolute=clock is not None, sequential=True)
        self._pending: DriverError | None = None
        self._divider = 1
        self._last_ticks: int | None = None
        self._last_seq = 0
        self._seq_full = -1
        self._in_signal_loss = False
        self.streaming = False
        self.stats = GratingStats()

    # ---- port

    def _before_close(self) -> None:
        """Stop streaming if possible (never raises)."""
        if self.streaming:
            with contextlib.suppress(DriverError):
                self._command(STOP, b"", retries=0, timeout_s=min(self.timeout_s, 0.2))
        self.streaming = False

    # ---- commands

    def _command(self, cmd: int, payload: bytes, *, retries: int, timeout_s: float) -> Frame:
        def is_reply(f: Frame) -> bool:
            if cmd == STATUS_Q:
                return f.type == STATUS and len(f.payload) == STATUS_PAYLOAD.size
            return f.type == ACK and f.payload[:1] == bytes([cmd])

        reply = self.framed.request(cmd, payload, is_reply, timeout_s=timeout_s, retries=retries)
        if reply.type == ACK:
            _, result = ACK_PAYLOAD.unpack(reply.payload)
            if result != 0:
                raise DeviceFault(DEVICE, f"command 0x{cmd:02X} rejected (result {result})")
        return reply

    def start_streaming(self, divider: int = 1) -> None:
        """Start the sample stream at 5 kHz / divider (retried: idempotent)."""
        if not 1 <= divider <= self.max_divider:
            raise LimitError(
                DEVICE,
                "bad rate divider",
                field="divider",
                value=divider,
                allowed=f"1 .. {self.max_divider}",
            )
        self.framed.reset()
        self._pending = None
        self._unwrap.reset()  # before START: the first sample is stamped after it
        self._command(START, START_PAYLOAD.pack(divider), retries=self.retries, timeout_s=self.timeout_s)
        self._divider = divider
        self._last_ticks = None
        self._seq_full = -1
        self._in_signal_loss = False
        self.streaming = True

    def stop_streaming(self) -> None:
        """Stop the stream (retried: idempotent); unread samples are discarded."""
        self._command(STOP, b"", retries=self.retries, timeout_s=self.timeout_s)
        self.streaming = False
        self.framed.reset()
        self._pending = None

    def status(self) -> dict[str, object]:
        """Board status (a query, retried): streaming, divider, ticks, error, warning."""
        reply = self._command(STATUS_Q, b"", retries=self.retries, timeout_s=self.timeout_s)
        streaming, divider, ticks, flags = STATUS_PAYLOAD.unpack(reply.payload)
        return {
            "streaming": bool(streaming),
            "divider": divider,
            "ticks": ticks,
            "error": not flags & 1,
            "warning": not flags & 2,
        }

    @property
    def crc_errors(self) -> int:
        """Frames dropped for a bad CRC-16 or BiSS CRC-6."""
        return self.framed.parser.crc_errors + self.stats.biss_crc_errors

    @property
    def frame_errors(self) -> int:
        """Truncated, garbled or unexpected frames (and garbage stretches)."""
        return self.framed.parser.frame_errors

    @property
    def rate_hz(self) -> float:
        return BASE_RATE_HZ / self._divider

    # ---- stream

    def _signal_fault(self) -> DeviceFault:
        return DeviceFault(
            DEVICE,
            f"read-head signal lost: BiSS error bit active ({self.stats.invalid_samples} invalid samples so far)",
            field="nE",
            value=0,
        )

    def read_block(
        self, max_samples: int = 5000, timeout_s: float | None = None, *, gather: bool = False
    ) -> SampleBlock:
        """The samples that have arrived (at least one), waiting at most timeout_s; with `gather`, waiting
        (at most timeout_s) until max_samples have.

        Errors are raised after the good samples that preceded them have been
        returned (on the next call); the stream stays usable afterwards.
        """
        if self._pending is not None:
            pending, self._pending = self._pending, None
            raise pending
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        deadline_s = self._link_clock.now_s() + timeout_s
        period_ticks = TICKS_PER_CYCLE * self._divider
        seqs: list[int] = []
        times: list[float] = []
        zs: list[float] = []
        warns: list[bool] = []
        lost_here = 0
        stats = self.stats
        fp = self.framed
        unpack = SAMPLE_PAYLOAD.unpack
        host_s = self._unwrap.clock.now_s()

        def block() -> SampleBlock:
            return SampleBlock(
                np.array(seqs, dtype=np.int64),
                np.array(times) * TICK_S,
                np.array(zs) * 1e-9 * NM_PER_COUNT,
                np.array(warns, dtype=bool),
                lost_here,
            )

        def take(seq16: int, raw: int, pos: int, error: bool, warning: bool, crc_ok: bool) -> DriverError | None:
            """One sample into the block (or dropped, counted); the error it raises, if any."""
            nonlocal lost_here
            if not crc_ok:
                stats.biss_crc_errors += 1
                return ChecksumError(DEVICE, f"BiSS CRC-6 mismatch in sample seq {seq16}; sample dropped")
            ticks = self._unwrap.unwrap_ticks(raw, host_s)
            lost, err = self._account(seq16, ticks, period_ticks)
            if lost < 0:
                return None  # duplicate
            lost_here += lost
            if err is None and error:
                stats.invalid_samples += 1
                if self._in_signal_loss:
                    return None
                self._in_signal_loss = True
                return self._signal_fault()
            if err is None:
                self._in_signal_loss = False
                seqs.append(self._seq_full)
                times.append(ticks)
                zs.append(pos)
                warns.append(warning)
                stats.samples += 1
                stats.warnings += warning
            return err

        while len(seqs) < max_samples:
            # Well-formed sample frames back to back (the stream's usual state) are parsed and checked in bulk;
            # anything else, one item at a time: the same samples and errors in the same order either way.
            run = fp.peek_run(SAMPLE, SAMPLE_PAYLOAD.size, max_samples - len(seqs), min_frames=BULK_MIN_FRAMES)
            if len(run):
                seq16s, raws, words = sample_fields(run)
                taken = 0
                err = None
                for sample in zip(seq16s, raws, *decode_biss_np(words), strict=True):  # at most max_samples
                    taken += 1
                    err = take(*sample)
                    if err is not None:
                        break
                fp.consume_run(taken, SAMPLE_PAYLOAD.size)
            else:
                item = fp.poll_item()
                if item is None:
                    if seqs:
                        break
                    left_s = deadline_s - self._link_clock.now_s()
                    if left_s <= 0:
                        if self._in_signal_loss:
                            raise self._signal_fault()
                        raise DeviceTimeout(DEVICE, f"no sample within {timeout_s:g} s")
                    fp.fill(left_s, (max_samples - len(seqs)) * SAMPLE_FRAME_LEN if gather else 1)
                    host_s = self._unwrap.clock.now_s()
                    continue
                if isinstance(item, FrameError):
                    err = item
                elif item.type == SAMPLE and len(item.payload) == SAMPLE_PAYLOAD.size:
                    seq16, raw, word_b = unpack(item.payload)
                    err = take(seq16, raw, *decode_biss(int.from_bytes(word_b, "big")))
                elif item.type == SAMPLE:
                    err = FrameError(DEVICE, f"sample frame of {len(item.payload)} bytes")
                else:
                    continue  # a late ACK or STATUS
            if err is not None:
                if seqs:
                    self._pending = err
                    break
                raise err
        return block()

    def _account(self, seq16: int, ticks: int, period_ticks: int) -> tuple[int, FrameError | None]:
        """Samples lost before this one, from time stamps checked against seq; -1: duplicate."""
        err = None
        if self._last_ticks is None:
            lost = 0
            self._seq_full = seq16
        else:
            steps = round((ticks - self._last_ticks) / period_ticks)
            if steps <= 0:
                return -1, None
            if (self._last_seq + steps - seq16) % 65536 != 0:
                err = FrameError(
                    DEVICE,
                    f"sequence {seq16} disagrees with its time stamp ({steps} periods after seq {self._last_seq})",
                )
            lost = steps - 1
            self._seq_full += steps
        self._last_ticks = ticks
        self._last_seq = seq16
        self.stats.lost_samples += lost
        return lost, err

    def samples(self, timeout_s: float | None = None) -> Iterator[GratingSample]:
        """Samples one by one, for as long as the caller iterates (errors propagate)."""
        while True:
            b = self.read_block(timeout_s=timeout_s)
            for i in range(len(b)):
                yield GratingSample(int(b.seq[i]), float(b.t_s[i]), float(b.z_m[i]), bool(b.warning[i]))

    def read_for(self, n_samples: int, timeout_s: float | None = None) -> SampleBlock:
        """Exactly n_samples samples concatenated (errors propagate)."""
        parts: list[SampleBlock] = []
        got = 0
        while got < n_samples:
            b = self.read_block(max_samples=n_samples - got, timeout_s=timeout_s, gather=True)
            parts.append(b)
            got += len(b)
        return SampleBlock(
            np.concatenate([p.seq for p in parts]),
            np.concatenate([p.t_s for p in parts]),
            np.concatenate([p.z_m for p in parts]),
            np.concatenate([p.warning for p in parts]),
            sum(p.lost for p in parts),
        )
