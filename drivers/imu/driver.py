"""Strapdown IMU (RLG triad and quartz accelerometer triad) streaming increments over RS-422.

The IMU integrates its gyros and accelerometers over each sample period (200, 400, 500 or
1000 Hz) and streams the angle and velocity increments, time-stamped, in the shared binary
framing of `drivers.serial_port` (sync A5 5A, type, u16 length, payload, CRC-16/CCITT),
little-endian.

Host -> IMU
    0x40 START    (empty)                 stream one SAMPLE per sample period
    0x41 STOP     (empty)
    0x42 INFO?    (empty)
    0x43 RATE     u16 rate_hz                (not while streaming)
IMU -> host
    0xC0 ACK      u8 command, u8 result (0 OK, 1 bad argument, 2 busy: streaming)
    0xC2 INFO     u16 rate_hz, f64 gyro LSB (rad), f64 accelerometer LSB (m/s), u8 streaming, 16s serial
    0x50 SAMPLE   u32 seq, u32 ticks, 3 x i32 angle increments (gyro LSB), 3 x i32 velocity
                  increments (accelerometer LSB), u8 status

seq counts samples from 0 at START; ticks is the 50 ns time stamp of the end of the sample's
interval (the interval is (t - 1/rate, t]), on the station clock's time base. A sample that
does not fit the IMU's transmit FIFO is dropped and seq still counts it, so a reader that
falls behind sees a gap, never a backlog. Status bits: 0 gyro fault (lasing or dither lost),
1 accelerometer fault or saturation, 2 over-temperature.

Errors: no reply or no sample within `silence_s` while streaming -> DeviceTimeout; bad CRC ->
ChecksumError; truncated or garbled frame -> FrameError (resynchronised on the next sync; the
good samples before it are returned first); a seq that disagrees with its time stamp ->
FrameError; status bits -> DeviceFault (field "status"); rate not supported -> LimitError
(nothing sent); port gone -> Disconnected. START, STOP, INFO? and RATE are idempotent and
retried.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import numpy as np

from drivers.errors import DeviceFault, DeviceTimeout, DriverError, FrameError, LimitError
from drivers.imu.protocol import (
    ACK,
    ACK_PAYLOAD,
    ACK_RESULTS,
    DEVICE,
    INFO,
    INFO_PAYLOAD,
    INFO_Q,
    RATE,
    RATE_PAYLOAD,
    RATES_HZ,
    SAMPLE,
    SAMPLE_DTYPE,
    START,
    STATUS_BITS,
    STOP,
)
from drivers.serial_port import TICK_S, Frame, FramedDevice, TickUnwrapper
from station.clock import Clock


@dataclass(frozen=True)
class ImuInfo:
    rate_hz: int
    gyro_lsb_rad: float
    accel_lsb_mps: float
    streaming: bool
    serial: str


@dataclass
class ImuBlock:
    """Consecutive samples; `lost` samples went missing before or among them."""

    seq: np.ndarray  # int64
    t_s: np.ndarray  # end of each sample's interval
    dtheta_rad: np.ndarray  # (n, 3)
    dv_mps: np.ndarray  # (n, 3)
    lost: int = 0

    def __len__(self) -> int:
        return len(self.seq)


@dataclass
class ImuRecording:
    """Samples gathered without loss (`add` refuses a gap)."""

    dt_s: float
    blocks: list[ImuBlock] = field(default_factory=list)

    def add(self, block: ImuBlock) -> None:
        if block.lost:
            raise DriverError(DEVICE, f"{block.lost} samples lost while recording: the record has a hole")
        self.blocks.append(block)

    @property
    def last_t_s(self) -> float:
        return float(self.blocks[-1].t_s[-1]) if self.blocks and len(self.blocks[-1]) else float("-inf")

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_s, dtheta_rad, dv_mps) of the whole record."""
        parts = [b for b in self.blocks if len(b)]
        return (np.concatenate([b.t_s for b in parts]), np.concatenate([b.dtheta_rad for b in parts]),
                np.concatenate([b.dv_mps for b in parts]))  # fmt: skip


class StrapdownImu(FramedDevice):
    """Driver of the IMU. `clock`: the station clock, whose time base the IMU's stamps share."""

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 3_000_000,
        rate_hz: int = 200,
        timeout_s: float = 0.5,
        silence_s: float = 1.0,
        retries: int = 2,
        clock: Clock | None = None,
    ) -> None:
        if rate_hz not in RATES_HZ:
            raise LimitError(DEVICE, "rate not supported", field="rate_hz", value=rate_hz, allowed=str(RATES_HZ))
        super().__init__(port, baud, clock=clock)
        self.rate_hz = rate_hz
        self.timeout_s = timeout_s
        self.silence_s = silence_s
        self.retries = retries
        self._unwrap = TickUnwrapper(clock, absolute=clock is not None, sequential=True)
        self._pending: DriverError | None = None
        self._next_seq: int | None = None
        self._last_ticks = 0
        self.info: ImuInfo | None = None
        self.streaming = False

    # ---- port

    def _after_open(self) -> None:
        """Set the sample rate and read the IMU's scale factors."""
        self._command(STOP, b"")
        self._command(RATE, RATE_PAYLOAD.pack(self.rate_hz))
        self.info = self.query_info()

    def _before_close(self) -> None:
        """Stop the stream if possible (never raises)."""
        if self.streaming:
            with contextlib.suppress(DriverError):
                self.stop_stream()

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz

    # ---- commands

    def _command(self, cmd: int, payload: bytes) -> Frame:
        def is_reply(f: Frame) -> bool:
            if cmd == INFO_Q:
                return f.type == INFO and len(f.payload) == INFO_PAYLOAD.size
            return f.type == ACK and f.payload[:1] == bytes([cmd])

        reply = self.framed.request(cmd, payload, is_reply, timeout_s=self.timeout_s, retries=self.retries)
        if reply.type == ACK:
            _, result = ACK_PAYLOAD.unpack(reply.payload)
            if result:
                raise DeviceFault(DEVICE, f"command 0x{cmd:02X} rejected: {ACK_RESULTS.get(result, result)}",
                                  field="result", value=result)  # fmt: skip
        return reply

    def query_info(self) -> ImuInfo:
        rate, gyro_lsb, accel_lsb, streaming, serial = INFO_PAYLOAD.unpack(self._command(INFO_Q, b"").payload)
        if rate != self.rate_hz:
            raise DeviceFault(DEVICE, "IMU runs at another rate than set", field="rate_hz", value=rate,
                              allowed=str(self.rate_hz))  # fmt: skip
        return ImuInfo(rate, gyro_lsb, accel_lsb, bool(streaming), serial.rstrip(b"\0").decode("ascii", "replace"))

    def start_stream(self) -> None:
        """Start streaming (samples from before are discarded)."""
        self.framed.reset()
        self._pending = None
        self._next_seq = None
        self._unwrap.reset()
        self._command(START, b"")
        self.streaming = True

    def stop_stream(self) -> None:
        self._command(STOP, b"")
        self.streaming = False
        self.framed.reset()

    # ---- stream

    def read_block(self, max_samples: int = 4000, timeout_s: float | None = None) -> ImuBlock:
        """The samples that have arrived (at least one), waiting at most timeout_s (default silence_s).

        An error is raised after the good samples before it have been returned (on the next call).
        """
        if self._pending is not None:
            err, self._pending = self._pending, None
            raise err
        info = self.info
        if info is None:
            raise DriverError(DEVICE, "not open")
        wait_s = self.silence_s if timeout_s is None else timeout_s
        deadline_s = self._link_clock.now_s() + wait_s
        fp = self.framed
        payloads: list[bytes] = []
        while len(payloads) < max_samples:
            item = fp.poll_item()
            if item is None:
                if payloads:
                    break
                left_s = deadline_s - self._link_clock.now_s()
                if left_s <= 0:
                    raise DeviceTimeout(DEVICE, f"no sample within {wait_s:g} s (stream silent)")
                fp.fill(left_s)
                continue
            if isinstance(item, Frame) and item.type == SAMPLE and len(item.payload) != SAMPLE_DTYPE.itemsize:
                item = FrameError(DEVICE, f"sample frame of {len(item.payload)} bytes")
            if isinstance(item, FrameError):
                if not payloads:
                    raise item
                self._pending = item
                break
            if item.type == SAMPLE:
                payloads.append(item.payload)
        return self._decode(np.frombuffer(b"".join(payloads), dtype=SAMPLE_DTYPE), info)

    def _decode(self, raw: np.ndarray, info: ImuInfo) -> ImuBlock:
        bad = np.flatnonzero(raw["status"])
        if bad.size:
            bits = int(raw["status"][bad[0]])
            what = ", ".join(name for bit, name in STATUS_BITS.items() if bits >> bit & 1) or f"status {bits}"
            fault = DeviceFault(DEVICE, f"{what} in sample {int(raw['seq'][bad[0]])}", field="status", value=bits)
            if not bad[0]:
                raise fault
            self._pending, raw = fault, raw[: bad[0]]  # the good samples before it are measurements: kept
        seq = raw["seq"].astype(np.int64)
        ticks = self._unwrap.unwrap_array(raw["ticks"], self._unwrap.clock.now_s())
        period = round(1.0 / (info.rate_hz * TICK_S))
        fresh = self._next_seq is None
        dseq = np.diff(seq, prepend=seq[0] - 1 if self._next_seq is None else self._next_seq - 1)
        dticks = np.diff(ticks, prepend=ticks[0] - period if fresh else self._last_ticks)
        wrong = np.flatnonzero((dseq < 1) | (dticks != dseq * period))
        if wrong.size:
            raise FrameError(DEVICE, f"sample seq {int(seq[wrong[0]])} disagrees with its time stamp")
        self._next_seq, self._last_ticks = int(seq[-1]) + 1, int(ticks[-1])
        return ImuBlock(seq, ticks * TICK_S, raw["dtheta"] * info.gyro_lsb_rad, raw["dv"] * info.accel_lsb_mps,
                        int(np.sum(dseq - 1)))  # fmt: skip
