"""Driver-side serial helpers shared by every serial device driver.

One place for what all serial drivers do the same way:

- `SerialLink`: opens the port through `serial.serial_for_url` exactly as for
  real hardware (`exclusive=True`, so a second opener fails), reads what has
  arrived or waits for the first byte with the remaining time as the port's
  timeout (a read never blocks forever) and turns every pyserial/OS failure
  into a typed error from `drivers.errors`.
- `LineReader`: bounded ASCII line reads on top of a link (a partial line at
  the deadline is a truncated reply, not a hang).
- Binary framing (`encode_frame`, `FrameParser`) used by the grating and the
  counter/timer; its resynchronising parser reports garbage, truncated frames
  and CRC errors as typed errors and carries on with the next good frame.
- `TickUnwrapper`: 32-bit, 50 ns device time stamps to seconds.
- `with_retries`: retry a query (never a move) on timeouts and bad replies.

Binary frame (little-endian)::

    offset  size  field
    0       2     sync 0xA5 0x5A
    2       1     frame type
    3       2     payload length n (u16, at most MAX_PAYLOAD)
    5       n     payload
    5+n     2     CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over bytes 2 .. 4+n

I/O timeouts count the seconds of the link clock (`Clock.link`: the wall clock
for real and wall-paced simulated stations, as the transport is real); station
time stamps come from the device or from the station `Clock`.
"""

from __future__ import annotations

import binascii
import contextlib
import errno
import math
import struct
import termios
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Self, TypeVar

import numpy as np
import serial

from drivers import sim_serial  # noqa: F401  (puts the sim:// URL handler on pyserial's path before any open)
from drivers.errors import (
    ChecksumError,
    DeviceTimeout,
    Disconnected,
    DriverError,
    FrameError,
)
from station.clock import Clock, WallClock, host_clock

# ---------------------------------------------------------------- the port

# A line silent this long has finished its message: beyond a USB serial adapter's latency timer (FTDI's default
# 16 ms: it hands on what it holds at least that often) and 40 characters at 9600 baud.
QUIET_GAP_S = 0.05


class SerialLink:
    """An open serial port with bounded reads and typed errors.

    `port` is a device path (/dev/ttyUSB0 or an emulator's /dev/pts/N); the
    same code opens both. `clock` is the link clock (`Clock.link`, the host's
    wall clock by default) whose seconds the readers' deadlines count.
    """

    def __init__(
        self,
        device: str,
        port: str,
        baud: int,
        *,
        clock: Clock | None = None,
        write_timeout_s: float = 1.0,
    ) -> None:
        self.device = device
        self.port = port
        self.clock: Clock = clock if clock is not None else host_clock()
        try:
            self._ser = serial.serial_for_url(port, baud, timeout=0, write_timeout=write_timeout_s, exclusive=True)
        except serial.SerialException as exc:
            if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY):
                raise DriverError(device, f"serial port {port} is in use by another process ({exc})") from exc
            raise Disconnected(device, f"cannot open serial port {port}: {exc}") from exc
        except (OSError, ValueError) as exc:
            raise Disconnected(device, f"cannot open serial port {port}: {exc}") from exc

    @property
    def is_open(self) -> bool:
        return self._ser.is_open

    def _gone(self, exc: BaseException) -> Disconnected:
        return Disconnected(self.device, f"serial port {self.port} went away: {exc}")

    def write(self, data: bytes) -> None:
        """Write all of `data` or raise (DeviceTimeout if the line stays blocked)."""
        try:
            self._ser.write(data)
        except serial.SerialTimeoutException as exc:
            raise DeviceTimeout(self.device, f"write of {len(data)} bytes to {self.port} timed out") from exc
        except (serial.SerialException, OSError, TypeError) as exc:
            raise self._gone(exc) from exc

    def read_some(self, wait_s: float, want_bytes: int = 1, until: bytes | None = None, size: int = 4096) -> bytes:
        """Whatever has arrived, waiting at most `wait_s` until `want_bytes` have, or with `until`, until the
        first `until` (or `size` bytes) has: a reader of a stream that knows how much it needs, or of lines,
        wakes once, not once per USB frame; b'' if none."""
        try:
            n = self._ser.in_waiting
            if n >= want_bytes:
                return self._ser.read(n)
            # Setting the timeout reconfigures the port (flock, tcgetattr): only when we must wait.
            self._ser.timeout = max(wait_s, 0.0)
            if until is not None:
                return bytes(self._ser.read_until(until, size))
            data = self._ser.read(want_bytes)
            if not data:
                return b""
            n = self._ser.in_waiting
            return data + self._ser.read(n) if n else data
        except (serial.SerialException, OSError, TypeError, termios.error) as exc:  # tcgetattr on a vanished pty
            raise self._gone(exc) from exc

    def discard_until_quiet(self, max_s: float, quiet_s: float = QUIET_GAP_S) -> None:
        """Drop what arrives until the line has been silent for `quiet_s`, for at most `max_s`: after a reply
        that could not be parsed, its rest is still on its way and would be read as the start of the next."""
        deadline_s = self.clock.now_s() + max_s
        while (left_s := deadline_s - self.clock.now_s()) > 0 and self.read_some(min(quiet_s, left_s)):
            pass

    def discard_input(self) -> None:
        """Drop whatever the device sent and nobody read yet."""
        try:
            self._ser.reset_input_buffer()
        except (serial.SerialException, OSError, TypeError, termios.error) as exc:  # tcflush on a vanished pty
            raise self._gone(exc) from exc

    def close(self) -> None:
        """Close the port; never raises (closing a vanished port is fine)."""
        with contextlib.suppress(serial.SerialException, OSError, TypeError):
            self._ser.close()


# ---------------------------------------------------------------- ASCII lines


class SerialDevice:
    """The port's life cycle that every serial driver shares: open and close (both idempotent), use as
    a context manager, one transaction at a time under `_io`, replies timed on the link clock of the
    station clock `clock` (`_link_clock`). A subclass names itself in DEVICE, may talk to the device
    once the port is open (`_after_open`; a failure there closes the port again) and say goodbye
    before it closes (`_before_close`, best effort). This class reads lines (`lines`); FramedDevice
    reads binary frames (`framed`)."""

    DEVICE = "serial device"

    def __init__(self, port: str, baud: int, *, clock: Clock | None = None) -> None:
        self.port = port
        self.baud = baud
        self._link_clock: Clock = clock.link if clock is not None else host_clock()
        self._link: SerialLink | None = None
        self._lines: LineReader | None = None
        self._io = threading.Lock()

    @property
    def is_open(self) -> bool:
        return self._link is not None

    def _connect(self) -> None:
        self._link = SerialLink(self.DEVICE, self.port, self.baud, clock=self._link_clock)
        self._lines = LineReader(self._link)

    def _disconnect(self) -> None:
        assert self._link is not None
        self._link.close()
        self._link = self._lines = None

    def open(self) -> Self:
        if not self.is_open:
            self._connect()
            try:
                self._after_open()
            except DriverError:
                self.close()
                raise
        return self

    def close(self) -> None:
        if not self.is_open:
            return
        self._before_close()
        self._disconnect()

    def _after_open(self) -> None:
        """Talk to the device once its port is open (nothing by default)."""

    def _before_close(self) -> None:
        """Best-effort goodbye to the device before the port closes (nothing by default)."""

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _not_open(self) -> DriverError:
        return DriverError(self.DEVICE, f"port {self.port} is not open")

    @property
    def lines(self) -> LineReader:
        if self._lines is None:
            raise self._not_open()
        return self._lines


class LineReader:
    """Bounded line reads: a complete line, a DeviceTimeout, or a FrameError."""

    def __init__(self, link: SerialLink, *, terminator: bytes = b"\n", max_len: int = 512):
        self.link = link
        self.terminator = terminator
        self.max_len = max_len
        self._buf = bytearray()

    def clear(self) -> None:
        self._buf.clear()

    def read_line(self, timeout_s: float) -> bytes:
        """The next line without its terminator (trailing CR stripped).

        Raises DeviceTimeout if nothing arrived within `timeout_s` (link clock), and
        FrameError if a partial line arrived and then stopped (truncated reply)
        or a line grew past `max_len` bytes.
        """
        clock = self.link.clock
        deadline_s = clock.now_s() + timeout_s
        while True:
            i = self._buf.find(self.terminator)
            if i >= 0:
                line = bytes(self._buf[:i])
                del self._buf[: i + len(self.terminator)]
                return line.rstrip(b"\r")
            if len(self._buf) > self.max_len:
                junk = bytes(self._buf[:64])
                self._buf.clear()
                raise FrameError(self.link.device, f"line longer than {self.max_len} bytes (starts {junk!r})")
            left_s = deadline_s - clock.now_s()
            if left_s <= 0:
                if self._buf:
                    partial = bytes(self._buf)
                    self._buf.clear()
                    raise FrameError(
                        self.link.device,
                        f"truncated reply {partial!r}: no line end within {timeout_s:g} s",
                    )
                raise DeviceTimeout(self.link.device, f"no reply within {timeout_s:g} s")
            self._buf += self.link.read_some(left_s, until=self.terminator, size=self.max_len + 1 - len(self._buf))


# ---------------------------------------------------------------- binary frames

SYNC = b"\xa5\x5a"
HEADER = struct.Struct("<2sBH")
CRC = struct.Struct("<H")
MAX_PAYLOAD = 2048
OVERHEAD = HEADER.size + CRC.size


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF); check value 0x29B1 for b'123456789'."""
    return binascii.crc_hqx(data, 0xFFFF)


def _crc16_table() -> np.ndarray:
    table = np.zeros(256, dtype=np.uint16)
    for byte in range(256):
        reg = byte << 8
        for _ in range(8):
            reg = ((reg << 1) ^ 0x1021) & 0xFFFF if reg & 0x8000 else (reg << 1) & 0xFFFF
        table[byte] = reg
    return table


CRC16_TABLE = _crc16_table()


def crc16_rows(rows: np.ndarray) -> np.ndarray:
    """crc16 of every row of a (n, k) uint8 array at once (table-driven, one column at a time)."""
    reg = np.full(len(rows), 0xFFFF, dtype=np.uint16)
    for column in rows.T:
        reg = (reg << np.uint16(8)) ^ CRC16_TABLE[(reg >> np.uint16(8)) ^ column]
    return reg


def encode_frame(frame_type: int, payload: bytes = b"") -> bytes:
    """One binary frame (see the module docstring)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = HEADER.pack(SYNC, frame_type, len(payload)) + payload
    return body + CRC.pack(crc16(memoryview(body)[2:]))


@dataclass(frozen=True, slots=True)
class Frame:
    type: int
    payload: bytes


class FrameParser:
    """Resynchronising parser of binary frames.

    `feed()` bytes, then call `next_item()` until it returns None (needs more
    bytes). Each item is a good `Frame` or an error instance (returned, not
    raised, so the caller chooses when to raise it); the offending bytes are
    already consumed, so parsing carries on with the next good frame:

    - CRC mismatch on a frame followed by a sync: ChecksumError (frame dropped);
    - a frame that does not end where the next sync starts (truncated or
      garbled), an impossible length, or garbage between frames: FrameError.

    One error is reported per bad stretch: bytes skipped while searching for
    the next good frame are counted, not reported again. Garbage before the
    first frame after `reset()` (joining a stream mid-frame) is silently skipped.
    """

    def __init__(self, device: str, *, max_payload: int = MAX_PAYLOAD) -> None:
        self.device = device
        self.max_payload = max_payload
        self._buf = bytearray()
        self._pos = 0
        self._synced = False
        self._resyncing = False
        self.skipped_bytes = 0
        self.crc_errors = 0
        self.frame_errors = 0

    def reset(self) -> None:
        self._buf.clear()
        self._pos = 0
        self._synced = False
        self._resyncing = False

    def feed(self, data: bytes) -> None:
        if self._pos > 65536:
            del self._buf[: self._pos]
            self._pos = 0
        self._buf += data

    def _skip_to_sync(self, start: int) -> int | None:
        """Move to the next sync at or after `start`; None if none buffered yet."""
        i = self._buf.find(SYNC, start)
        if i < 0:
            keep = len(self._buf) - 1 if self._buf.endswith(SYNC[:1]) else len(self._buf)
            self.skipped_bytes += keep - self._pos
            self._pos = max(keep, self._pos)
            return None
        self.skipped_bytes += i - self._pos
        self._pos = i
        return i

    def _bad(self, err: FrameError) -> FrameError | None:
        """Count an error; report it unless we are already inside a bad stretch."""
        if isinstance(err, ChecksumError):
            self.crc_errors += 1
        else:
            self.frame_errors += 1
        if self._resyncing or not self._synced:
            return None
        self._resyncing = not isinstance(err, ChecksumError)
        return err

    def peek_run(self, frame_type: int, payload_size: int, max_frames: int, min_frames: int = 1) -> np.ndarray:
        """The payloads (rows of a uint8 array) of the frames of `frame_type` and `payload_size` that follow
        at the parser's position back to back, each with its sync, header and a good CRC, at most max_frames;
        nothing is consumed (consume_run). What next_item would return one by one for them, in bulk. Empty
        while fewer than min_frames such frames could be buffered (in bulk, a handful costs more than singly)."""
        frame_len = HEADER.size + payload_size + CRC.size
        n = min((len(self._buf) - self._pos) // frame_len, max_frames)
        if n < max(min_frames, 1):
            return np.empty((0, payload_size), dtype=np.uint8)
        rows = np.frombuffer(self._buf, dtype=np.uint8, count=n * frame_len, offset=self._pos).reshape(n, frame_len)
        crc_rx = rows[:, -2].astype(np.uint16) | (rows[:, -1].astype(np.uint16) << np.uint16(8))
        good = (
            (rows[:, 0] == SYNC[0])
            & (rows[:, 1] == SYNC[1])
            & (rows[:, 2] == frame_type)
            & (rows[:, 3] == payload_size & 0xFF)
            & (rows[:, 4] == payload_size >> 8)
            & (crc16_rows(rows[:, 2:-2]) == crc_rx)
        )
        k = n if good.all() else int(np.argmin(good))
        return rows[:k, HEADER.size : HEADER.size + payload_size].copy()  # a copy: feed() may move the buffer

    def consume_run(self, n_frames: int, payload_size: int) -> None:
        """Take the first n_frames of a peek_run off the buffer, as next_item would have."""
        if n_frames > 0:
            self._pos += n_frames * (HEADER.size + payload_size + CRC.size)
            self._synced = True
            self._resyncing = False

    def next_item(self) -> Frame | FrameError | None:
        buf = self._buf
        while True:
            start = self._pos
            if len(buf) - start < 2:
                return None
            if buf[start] != 0xA5 or buf[start + 1] != 0x5A:
                i = self._skip_to_sync(start + 1)
                err = self._bad(FrameError(self.device, "garbage between frames; resynchronising on the next sync"))
                if err is not None:
                    return err
                if i is None:
                    return None
                continue
            if len(buf) - start < HEADER.size:
                return None
            _, ftype, n = HEADER.unpack_from(buf, start)
            if n > self.max_payload:
                self._skip_to_sync(start + 1)
                err = self._bad(FrameError(self.device, f"impossible frame length {n} (max {self.max_payload})"))
                if err is not None:
                    return err
                continue
            end = start + HEADER.size + n + CRC.size
            if len(buf) < end:
                return None
            (crc_rx,) = CRC.unpack_from(buf, end - CRC.size)
            crc_calc = crc16(memoryview(buf)[start + 2 : end - CRC.size])
            if crc_rx == crc_calc:
                self._pos = end
                self._synced = True
                self._resyncing = False
                return Frame(ftype, bytes(buf[start + HEADER.size : end - CRC.size]))
            # Bad CRC: an intact frame with a wrong CRC is followed by a sync;
            # a truncated or garbled one is not (wait for two more bytes to tell).
            if len(buf) < end + 2:
                return None
            if buf[end : end + 2] == SYNC:
                self._pos = end
                err = self._bad(
                    ChecksumError(
                        self.device,
                        f"frame type 0x{ftype:02X}: CRC 0x{crc_rx:04X} != computed 0x{crc_calc:04X}; frame dropped",
                    )
                )
            else:
                self._skip_to_sync(start + 1)
                err = self._bad(
                    FrameError(
                        self.device,
                        f"truncated or garbled frame (type 0x{ftype:02X}, length {n}); resynchronising",
                    )
                )
            if err is not None:
                return err


class FramedPort:
    """A serial link speaking the binary framing: request/reply plus a frame stream.

    Frames that arrive while a request waits for its reply (stream samples,
    events) are kept in a backlog and handed out by `poll_item` afterwards,
    so a status query in the middle of a stream loses nothing. `clock`: the
    link clock, as for SerialLink.
    """

    def __init__(self, device: str, port: str, baud: int, *, clock: Clock | None = None) -> None:
        self.device = device
        self.link = SerialLink(device, port, baud, clock=clock)
        self.parser = FrameParser(device)
        self._backlog: deque[Frame] = deque()

    def close(self) -> None:
        self.link.close()

    def reset(self) -> None:
        """Forget everything received so far (before starting a new stream)."""
        self.link.discard_input()
        self.parser.reset()
        self._backlog.clear()

    def poll_item(self) -> Frame | FrameError | None:
        """The next frame or framing error already received; None if none (no I/O)."""
        if self._backlog:
            return self._backlog.popleft()
        return self.parser.next_item()

    def peek_run(self, frame_type: int, payload_size: int, max_frames: int, min_frames: int = 1) -> np.ndarray:
        """FrameParser.peek_run on what poll_item would hand out next (nothing while a backlog waits)."""
        if self._backlog:
            return np.empty((0, payload_size), dtype=np.uint8)
        return self.parser.peek_run(frame_type, payload_size, max_frames, min_frames)

    def consume_run(self, n_frames: int, payload_size: int) -> None:
        self.parser.consume_run(n_frames, payload_size)

    def fill(self, wait_s: float, want_bytes: int = 1) -> None:
        """Receive what arrives within wait_s (waits for want_bytes, at least one)."""
        self.parser.feed(self.link.read_some(wait_s, want_bytes))

    def request(
        self,
        frame_type: int,
        payload: bytes,
        is_reply: Callable[[Frame], bool],
        *,
        timeout_s: float,
        retries: int = 0,
        what: str = "",
    ) -> Frame:
        """Send a frame and return the first frame `is_reply` accepts.

        Retries (only pass retries > 0 for queries and idempotent commands) on
        no reply within timeout_s or a garbled reply.
        """
        label = what or f"command 0x{frame_type:02X}"
        clock = self.link.clock

        def once() -> Frame:
            self.link.write(encode_frame(frame_type, payload))
            deadline_s = clock.now_s() + timeout_s
            bad: FrameError | None = None
            while True:
                item = self.parser.next_item()
                if item is None:
                    left_s = deadline_s - clock.now_s()
                    if left_s <= 0:
                        if bad is not None:
                            raise type(bad)(self.device, f"{label}: reply damaged ({bad})")
                        raise DeviceTimeout(self.device, f"no reply to {label} within {timeout_s:g} s")
                    self.fill(left_s)
                elif isinstance(item, FrameError):
                    bad = item  # maybe our reply, maybe stream debris: keep waiting
                elif is_reply(item):
                    return item
                else:
                    self._backlog.append(item)

        return with_retries(once, retries)


# ---------------------------------------------------------------- time stamps

TICK_S = 50e-9
TICK_BITS = 32
ANCHOR_SLACK_S = 1.0  # a device clock may run this far behind the host's when a stream starts


class FramedDevice(SerialDevice):
    """A SerialDevice that speaks the binary frames of FramedPort."""

    def __init__(self, port: str, baud: int, *, clock: Clock | None = None) -> None:
        super().__init__(port, baud, clock=clock)
        self._port: FramedPort | None = None

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def _connect(self) -> None:
        self._port = FramedPort(self.DEVICE, self.port, self.baud, clock=self._link_clock)

    def _disconnect(self) -> None:
        assert self._port is not None
        self._port.close()
        self._port = None

    @property
    def framed(self) -> FramedPort:
        if self._port is None:
            raise self._not_open()
        return self._port


class TickUnwrapper:
    """Device time stamps (wrapping `bits`-bit counters of `tick_s`) to seconds.

    A 32-bit counter of 50 ns wraps every 214.7 s. Between two stamps the
    wrap count is chosen so that the device's elapsed time is the one closest
    to the elapsed time of `clock` between the two calls, which stays right
    for gaps of any length as long as the two time bases agree to within half
    a wrap (107 s).

    If `absolute` is true, the device time base is the station clock's (true
    for the emulators, and for boards whose timebase is reset at the clock's
    epoch): the first stamp takes the wrap count that puts it nearest to
    `clock.now_s()`. Otherwise times count from wrap 0 of the device counter.

    `sequential`: for a stream whose consecutive stamps are never half a wrap
    apart (a device that sends a heartbeat or a sample at least every few
    seconds while it streams, and whose silence the driver detects), each
    stamp is taken nearest to its predecessor (frames of different kinds may
    arrive a little out of time order) and the host clock only anchors the
    first. That stays right however late the host reads a backlog, which the
    host-elapsed rule does not once reading lags by half a wrap (a virtual
    clock running 1000x faster than the line).
    """

    def __init__(
        self,
        clock: Clock | None = None,
        *,
        absolute: bool = False,
        sequential: bool = False,
        tick_s: float = TICK_S,
        bits: int = TICK_BITS,
    ) -> None:
        self.clock: Clock = clock if clock is not None else WallClock()
        self.absolute = absolute
        self.sequential = sequential
        self.tick_s = tick_s
        self.modulus = 1 << bits
        self._last_ticks: int | None = None  # unwrapped
        self._last_host_s = 0.0
        self._not_before_s: float | None = None

    def reset(self) -> None:
        """Forget the history: the next stamp is anchored afresh, in absolute mode as the first one at
        or after this moment (less ANCHOR_SLACK_S), so however late the host reads it, it is right
        as long as it was stamped within a wrap of the command that started the stream."""
        self._last_ticks = None
        self._not_before_s = self.clock.now_s() - ANCHOR_SLACK_S

    def unwrap_ticks(self, raw: int, host_s: float | None = None) -> int:
        """Unwrapped tick count of a raw counter value.

        `host_s`: the clock reading when the stamp arrived (pass one reading
        per received chunk to save a clock call per stamp); read now if None.
        """
        if host_s is None:
            host_s = self.clock.now_s()
        mod = self.modulus
        if self._last_ticks is None:
            if not self.absolute:
                k = 0
            elif self._not_before_s is not None:
                k = math.ceil((self._not_before_s / self.tick_s - raw) / mod)
            else:
                k = round((host_s / self.tick_s - raw) / mod)
            full = k * mod + raw
        else:
            delta = (raw - self._last_ticks) % mod
            # sequential: nearest to the predecessor, since a heartbeat stream has no long silences
            expected = 0.0 if self.sequential else (host_s - self._last_host_s) / self.tick_s
            full = self._last_ticks + delta + round((expected - delta) / mod) * mod
        self._last_ticks = full
        self._last_host_s = host_s
        return full

    def unwrap_s(self, raw: int) -> float:
        return self.unwrap_ticks(raw) * self.tick_s

    def unwrap_array(self, raw: np.ndarray, host_s: float | None = None) -> np.ndarray:
        """Unwrapped ticks (int64) of stamps that arrived together, in time order.

        The first is unwrapped like `unwrap_ticks`; each following one lies
        less than a wrap after its predecessor.
        """
        raw = np.asarray(raw, dtype=np.int64)
        if raw.size == 0:
            return raw
        first = self.unwrap_ticks(int(raw[0]), host_s)
        steps = np.diff(raw) % self.modulus
        full = first + np.concatenate(([0], np.cumsum(steps)))
        self._last_ticks = int(full[-1])
        return full


def ticks_of(t_s: float, *, tick_s: float = TICK_S, bits: int = TICK_BITS) -> int:
    """Raw counter value of a device at time t_s (emulator side)."""
    return round(t_s / tick_s) % (1 << bits)


def ticks_of_array(t_s: np.ndarray, *, tick_s: float = TICK_S, bits: int = TICK_BITS) -> np.ndarray:
    """ticks_of of every element (int64; np.rint rounds half to even, as round() does)."""
    return np.rint(np.asarray(t_s, dtype=float) / tick_s).astype(np.int64) % (1 << bits)


# ---------------------------------------------------------------- retries

T = TypeVar("T")
RETRYABLE: tuple[type[DriverError], ...] = (DeviceTimeout, FrameError)


def with_retries(
    query: Callable[[], T],
    retries: int,
    *,
    retry_on: tuple[type[DriverError], ...] = RETRYABLE,
    before_retry: Callable[[], None] | None = None,
) -> T:
    """Run a side-effect-free query up to 1 + retries times.

    Only for queries and idempotent commands (status, position, stop): a move
    that timed out may have been carried out and must not be repeated blindly.
    The last error is re-raised with the attempt count in its message.
    """
    attempts = 1 + max(retries, 0)
    for attempt in range(1, attempts + 1):
        try:
            return query()
        except retry_on as exc:
            if attempt == attempts:
                if attempts > 1:
                    exc.args = (f"{exc.args[0]} (after {attempts} attempts)", *exc.args[1:])
                raise
            if before_retry is not None:
                before_retry()
    raise AssertionError("unreachable")
