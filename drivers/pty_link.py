"""Pseudo-terminal plumbing shared by the serial device emulators.

An emulator owns the master side of a pty; the driver opens the slave's tty
path (`port`) with pyserial exactly as it would open /dev/ttyUSB0. One worker
thread per emulator multiplexes the link with `select`: it reads the driver's
bytes and hands them to `on_bytes`, calls `on_poll(now_s)` with the station
time, and drains the output queue into the pty.

Time. Every time stamp comes from `clock.now_s()` (the world's clock, wall or
virtual); the thread only *wakes* on the link clock (`clock.link`, the wall
clock for wall and wall-paced virtual clocks: `poll_wall_s`, the select
timeout), so it never sleeps in station time and a VirtualClock running
faster than real time simply makes each poll cover more station time.

Rate limit. Output is paced like a UART at `baud` in link-clock (wall) time
(baud/10 bytes per second, token bucket of `burst_wall_s`) and queued in a bounded
transmit FIFO (`fifo_bytes`). Streaming emulators ask `tx_room()` before
producing and drop what does not fit, counting it in their own sequence
numbers, as a real interface board whose FIFO overflows would; so a fast
virtual clock yields visible gaps, never an unbounded backlog or a flooded pty.

Faults (`inject`) are armed from the test or control side and consumed by the
emulator at its next opportunity; `disconnect()` closes the master, which the
driver sees as an I/O error on its port, like a pulled USB cable.

Instead of a pty, `start_sim()` puts the emulator on a `sim://` line
(drivers.sim_serial): no thread, the port's user calls the hooks, and the line
is paced in station time. `next_due_s` tells that line when to poll again.
"""

from __future__ import annotations

import contextlib
import enum
import itertools
import os
import select
import threading
import tty
from collections.abc import Callable

from drivers import sim_serial
from station.clock import Clock

SIM_POLL_S = 0.002  # station seconds between polls of an emulator on a sim:// line (the pty worker's poll)
# On a sim:// line a stream is made in batches of this much station time, as a USB-serial bridge hands its
# buffer on (a reader of blocks wakes 20 times a second instead of once per 2 ms poll). Far below silence_s.
SIM_STREAM_BATCH_S = 0.05
_sim_ids = itertools.count(1)


class Fault(enum.Enum):
    """Faults an emulator can inject (each emulator supports those that apply)."""

    NO_ANSWER = "no_answer"  # ignore commands; streaming emulators also go silent
    GARBLE = "garble"  # corrupt the next frame/reply
    TRUNCATE = "truncate"  # cut the next frame/reply short
    CRC_ERROR = "crc_error"  # next frame/reply carries a wrong CRC/checksum
    DISCONNECT = "disconnect"  # close the link (mid-stream if streaming)
    SIGNAL_LOSS = "signal_loss"  # read head loses its signal (grating/reference)
    OVERSPEED = "overspeed"  # reference read head overspeed alarm
    COUNTER_OVERFLOW = "counter_overflow"  # counter/timer pulse count overflows
    LOST_REPLY = "lost_reply"  # carry out the next command but lose its reply (counter/timer)


# What every framed serial link can suffer; a device's emulator adds its own (signal loss, overflow, ...).
LINK_FAULTS: frozenset[enum.Enum] = frozenset(
    {Fault.NO_ANSWER, Fault.GARBLE, Fault.TRUNCATE, Fault.CRC_ERROR, Fault.DISCONNECT}
)


class FaultBox:
    """Armed faults: `count` occurrences each, or persistent until cleared (count=None)."""

    def __init__(self, supported: frozenset[enum.Enum]) -> None:
        self.supported = supported
        self._lock = threading.Lock()
        self._armed: dict[enum.Enum, int | None] = {}

    def inject(self, fault: enum.Enum, count: int | None = 1) -> None:
        if fault not in self.supported:
            raise ValueError(f"fault {fault.value!r} not supported here")
        with self._lock:
            self._armed[fault] = count

    def clear(self, fault: enum.Enum | None = None) -> None:
        with self._lock:
            if fault is None:
                self._armed.clear()
            else:
                self._armed.pop(fault, None)

    def active(self, fault: enum.Enum) -> bool:
        """True while armed, without consuming it."""
        if not self._armed:  # checked on every frame: most boxes are empty (a racing inject counts from the next)
            return False
        with self._lock:
            return fault in self._armed

    def take(self, fault: enum.Enum) -> bool:
        """True if armed; consumes one occurrence."""
        if not self._armed:
            return False
        with self._lock:
            if fault not in self._armed:
                return False
            left = self._armed[fault]
            if left is not None:
                if left <= 1:
                    del self._armed[fault]
                else:
                    self._armed[fault] = left - 1
            return True


def garble(frame: bytes) -> bytes:
    """The frame with its first bytes and a middle byte inverted (breaks sync and CRC)."""
    b = bytearray(frame)
    for i in (0, 1, len(b) // 2):
        if i < len(b):
            b[i] ^= 0xFF
    return bytes(b)


def truncate(frame: bytes) -> bytes:
    """The first half of the frame."""
    return frame[: max(1, len(frame) // 2)]


class PtyEmulator:
    """Base of a serial emulator behind a pty; subclasses implement the protocol.

    Subclass hooks (run on the worker thread only, or on a sim:// line under its
    lock, so they need no locking among themselves): `on_bytes(data)`,
    `on_poll(now_s)`, `on_disconnect()`, and `next_due_s(now_s)` for a sim:// line.
    Subclasses call `send(data)` and `tx_room()`.
    """

    name = "emulator"
    supported_faults: frozenset[enum.Enum] = frozenset({Fault.NO_ANSWER, Fault.DISCONNECT})

    def __init__(
        self,
        clock: Clock,
        *,
        baud: int = 115_200,
        poll_wall_s: float = 0.002,
        fifo_bytes: int = 65_536,
        burst_wall_s: float = 0.02,
    ) -> None:
        self.clock = clock
        self._link_clock = clock.link
        self.baud = baud
        self.poll_wall_s = poll_wall_s
        self.fifo_bytes = fifo_bytes
        self._bytes_per_wall_s = baud / 10.0
        self._burst_bytes = max(64.0, self._bytes_per_wall_s * burst_wall_s)
        self.faults = FaultBox(self.supported_faults)
        self._tx = bytearray()
        self._line_buf = b""
        self._tokens = self._burst_bytes
        self._last_link_s = self._link_clock.now_s()
        self._master: int | None = None
        self._slave: int | None = None
        self._port = ""
        self._sim_name = ""
        self._stop = threading.Event()
        self._disconnect_now = threading.Event()
        self._thread: threading.Thread | None = None
        self._finished = self._link_clock.event()
        self._wake_line: Callable[[], None] = _nothing
        self.connected = False
        self.error: BaseException | None = None  # an exception that killed the worker

    # ---- lifecycle

    @property
    def port(self) -> str:
        """tty path or sim:// URL the driver opens (valid after start() or start_sim())."""
        if not self._port:
            raise RuntimeError(f"{self.name} not started")
        return self._port

    def start(self) -> str:
        """Open the pty and start the worker; returns the port path."""
        if self._port:
            raise RuntimeError(f"{self.name} already started")
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._port = os.ttyname(slave)
        self.connected = True
        self._thread = threading.Thread(target=self._run, name=f"{self.name}-pty", daemon=True)
        self._thread.start()
        return self._port

    def start_sim(self, name: str | None = None) -> str:
        """Serve a sim:// line instead of a pty (no thread); returns its URL (`port`)."""
        if self._port:
            raise RuntimeError(f"{self.name} already started")
        self._sim_name = name or f"{self.name}-{next(_sim_ids)}"
        self._port = sim_serial.register(self._sim_name, self)
        self.connected = True
        return self._port

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the worker and close the pty (idempotent)."""
        self._stop.set()
        self._wake_line()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._finished.wait(timeout_s=timeout_s)
        self._close_fds()
        if self._sim_name:
            sim_serial.unregister(self._sim_name)

    def __enter__(self) -> PtyEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def disconnect(self) -> None:
        """Pull the cable: close the master side now (the driver sees EIO)."""
        self._disconnect_now.set()
        self._wake_line()

    def inject(self, fault: enum.Enum, count: int | None = 1) -> None:
        """Arm a fault for `count` occurrences (None: until `clear_fault`)."""
        self.faults.inject(fault, 1 if fault is Fault.DISCONNECT else count)
        self._wake_line()

    def clear_fault(self, fault: enum.Enum | None = None) -> None:
        self.faults.clear(fault)

    def _close_fds(self) -> None:
        for attr in ("_master", "_slave"):
            fd = getattr(self, attr)
            if fd is not None:
                setattr(self, attr, None)
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.connected = False

    # ---- output

    def send(self, data: bytes) -> None:
        """Queue bytes for the driver (dropped if the FIFO is full: see tx_room)."""
        if len(self._tx) + len(data) <= self.fifo_bytes:
            self._tx += data

    def tx_room(self) -> int:
        """Free bytes in the transmit FIFO."""
        return self.fifo_bytes - len(self._tx)

    def tx_pending(self) -> int:
        """Bytes in the transmit FIFO."""
        return len(self._tx)

    def peek_tx(self, n: int) -> bytes:
        """The first n bytes of the transmit FIFO, left in it."""
        return bytes(self._tx[:n])

    def take_tx(self, n: int) -> bytes:
        """Remove and return the first n bytes of the transmit FIFO (what a sim:// line carries)."""
        data = bytes(self._tx[:n])
        del self._tx[:n]
        return data

    def _refill(self) -> None:
        """Add the tokens the line earned since the last refill (link-clock time, the UART's pace)."""
        now_s = self._link_clock.now_s()
        self._tokens = min(self._burst_bytes, self._tokens + (now_s - self._last_link_s) * self._bytes_per_wall_s)
        self._last_link_s = now_s

    def _drain(self) -> None:
        self._refill()
        n = min(len(self._tx), int(self._tokens))
        if n <= 0 or self._master is None:
            return
        try:
            written = os.write(self._master, self._tx[:n])
        except BlockingIOError:
            return
        del self._tx[:written]
        self._tokens -= written

    def _disconnect_due(self) -> bool:
        return self._disconnect_now.is_set() or self.faults.take(Fault.DISCONNECT)

    # ---- sim:// line

    def attach_line(self, wake: Callable[[], None]) -> None:
        """`wake` ends a sim:// reader's wait: called when a fault is injected, the cable pulled or the
        emulator closed, so that an emulator whose `next_due_s` lies far ahead is seen to fail at once."""
        self._wake_line = wake

    def sim_link_error(self) -> str | None:
        """Why a sim:// port can no longer talk to the emulator (None while it can); a pending
        disconnect happens now."""
        if self._stop.is_set():
            return f"{self.name} closed"
        if self.connected and self._disconnect_due():
            self.connected = False
            self.on_disconnect()
        return None if self.connected else f"{self.name} disconnected"

    # ---- worker

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._disconnect_due():
                    self._close_fds()
                    self.on_disconnect()
                    return
                master = self._master
                if master is None:
                    return
                want_write = [master] if self._tx else []
                wait = self.poll_wall_s
                if self._tx and self._tokens < 1:
                    wait = min(wait, 1.0 / self._bytes_per_wall_s)
                readable, _, _ = select.select([master], want_write, [], wait)
                if readable:
                    try:
                        data = os.read(master, 4096)
                    except BlockingIOError:
                        data = b""
                    except OSError:
                        # EIO should not happen while we hold the slave; back off, keep serving.
                        self._link_clock.sleep_s(self.poll_wall_s)
                        data = b""
                    if data:
                        self.on_bytes(data)
                self.on_poll(self.clock.now_s())
                if self._tx:
                    self._drain()
                else:
                    self._refill()
        except BaseException as exc:  # keep the cause for tests; the driver sees a dead link
            self.error = exc
            self._close_fds()
            raise
        finally:
            self._finished.set()

    # ---- line protocols

    def command_lines(self, data: bytes, max_len: int = 1024) -> list[bytes]:
        """The command lines that `data` completes: stripped, empty ones dropped, and those that an armed
        NO_ANSWER fault swallows left out. A partial line longer than max_len is garbage and let go."""
        self._line_buf += data
        *lines, rest = self._line_buf.split(b"\n")
        self._line_buf = rest if len(rest) <= max_len else b""
        return [line for line in map(bytes.strip, lines) if line and not self.faults.take(Fault.NO_ANSWER)]

    # ---- protocol hooks

    def on_bytes(self, data: bytes) -> None:
        """Bytes from the driver."""

    def on_poll(self, now_s: float) -> None:
        """Called every poll with the station time; produce streamed output here."""

    def on_disconnect(self) -> None:
        """The link was closed by a DISCONNECT fault."""

    def next_due_s(self, now_s: float) -> float:
        """When a sim:// line should next call on_poll, if nothing else wakes it (a command, a fault, a pulled
        cable): by default a poll every SIM_POLL_S; an emulator that knows when its output is due can say so."""
        return now_s + SIM_POLL_S

    @staticmethod
    def stream_due_s(next_sample_s: float, now_s: float) -> float:
        """next_due_s of a stream whose next sample falls due at next_sample_s: its batch (SIM_STREAM_BATCH_S)."""
        return max(next_sample_s + SIM_STREAM_BATCH_S, now_s + SIM_POLL_S)


def _nothing() -> None:
    """No sim:// line to wake (a pty, or not started)."""
