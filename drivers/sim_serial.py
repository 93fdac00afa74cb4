"""`sim://<name>`: a serial port whose far end is an emulator called in the port user's thread.

`register(name, emulator)` puts an emulator on a simulated line and returns its
URL; `serial.serial_for_url("sim://<name>")` opens it (the handler is
`drivers.protocol_sim`: the `devices` package is on pyserial's search path once
this module is imported), so a driver opens a device path, a pty or a sim:// URL
with the same code.

The line (`SimLine`), in the station time of the emulator's clock:

- a write hands the bytes to the emulator's `on_bytes` at once;
- a read first lets the emulator produce what is due (`on_poll(now_s)`, once
  its `next_due_s` has come or after a write, as the pty worker polls every
  2 ms), then takes from its transmit FIFO what a UART at the emulator's baud
  (baud/10 bytes per station second) has carried by now; while that is too
  little it waits on the clock until the adapter hands over the next bytes
  (on a 1 ms USB frame grid) or the emulator is next due, at most the port's
  timeout, counted in the same seconds; a fault injected or the cable pulled
  meanwhile wakes it at once;
- `read_until` (pyserial's API for lines) waits the same way for the first
  terminator, and wakes once, at the USB frame that brings it: a driver reading
  lines does not wake once a frame for each byte of its reply;
- a pulled cable (`disconnect()`, a DISCONNECT fault) or a closed emulator
  makes every call raise SerialException, as a vanished pty does.

An exclusive open (`exclusive=True`) of a line held exclusively fails with
errno EBUSY, as the second exclusive opener of a tty does.
"""

from __future__ import annotations

import errno
import math
import threading
from collections.abc import Callable
from typing import Protocol

import serial

from station.clock import Clock

SCHEME = "sim"
HANDLER_PACKAGE = "drivers"  # pyserial imports drivers.protocol_sim for sim:// URLs
# A USB-serial adapter hands what it received to the host once per 1 ms USB frame: a waiting read wakes on
# that grid and takes every byte carried by then (not one wake per byte of a 3 Mbaud stream).
HOST_LATENCY_S = 0.001
CARRY_SLACK_BYTES = 1e-6  # a read woken at a byte's due time takes that byte despite rounding

if HANDLER_PACKAGE not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(HANDLER_PACKAGE)


class SimEmulator(Protocol):
    """What a line needs of its emulator (drivers.pty_link.PtyEmulator provides it)."""

    clock: Clock
    baud: int

    def on_bytes(self, data: bytes) -> None: ...

    def on_poll(self, now_s: float) -> None: ...

    def next_due_s(self, now_s: float) -> float: ...

    def tx_pending(self) -> int: ...

    def peek_tx(self, n: int) -> bytes: ...

    def take_tx(self, n: int) -> bytes: ...

    def sim_link_error(self) -> str | None: ...

    def attach_line(self, wake: Callable[[], None]) -> None: ...


class SimLine:
    """The simulated serial line between the ports opened on `sim://<name>` and one emulator."""

    def __init__(self, name: str, emulator: SimEmulator) -> None:
        self.name = name
        self.url = f"{SCHEME}://{name}"
        self.emulator = emulator
        self.clock = emulator.clock
        self._bytes_per_s = emulator.baud / 10.0
        self._lock = threading.Lock()
        self._rx = bytearray()  # carried to the host, not read yet
        self._carried_s = self.clock.now_s()  # the line's capacity is accounted up to here
        self._poll_due_s = self._carried_s
        self._exclusive = False
        self._changed = self.clock.event()
        emulator.attach_line(self._changed.set)  # a fault or a pulled cable ends a wait at once

    # ---- opening

    def acquire(self, exclusive: bool) -> None:
        with self._lock:
            self._check()
            if exclusive:
                if self._exclusive:
                    raise serial.SerialException(errno.EBUSY, f"could not exclusively open {self.url}: in use")
                self._exclusive = True

    def release(self, exclusive: bool) -> None:
        with self._lock:
            if exclusive:
                self._exclusive = False
        self._changed.set()

    # ---- I/O (every call raises SerialException once the link is down)

    def write(self, data: bytes) -> None:
        with self._lock:
            self._check()
            now_s = self.clock.now_s()
            self._service(now_s)  # what was due before the command arrives happens first (a latched alarm)
            self.emulator.on_bytes(data)
            self._poll_due_s = now_s
        self._changed.set()

    def in_waiting(self) -> int:
        with self._lock:
            self._service(self.clock.now_s())
            return len(self._rx)

    def read(self, size: int, timeout_s: float | None, is_open: Callable[[], bool]) -> bytes:
        """Up to `size` bytes: returns once it has them, or when timeout_s (None: no limit) has passed
        or the port closed with fewer."""
        return self.read_until(None, size, timeout_s, is_open)

    def read_until(
        self, terminator: bytes | None, size: int, timeout_s: float | None, is_open: Callable[[], bool]
    ) -> bytes:
        """Through the first `terminator` (None: none), or `size` bytes: returns once it has them, or with what has
        come when timeout_s (None: no limit) has passed or the port closed. It wakes once, at the USB frame that
        brings the terminator (the station time a reader of single bytes returns it too), not once a frame."""
        clock = self.clock
        now_s = clock.now_s()
        deadline_s = math.inf if timeout_s is None else now_s + timeout_s
        while True:
            self._changed.clear()
            with self._lock:
                self._service(now_s)
                rx = self._rx
                end = rx.find(terminator) if terminator else -1
                n = min(size, len(rx) if end < 0 else end + len(terminator or b""))
                if end >= 0 or n >= size or now_s >= deadline_s or not is_open():
                    out = bytes(rx[:n])
                    del rx[:n]
                    return out
                wake_s = min(deadline_s, self._next_s(now_s, self._until_bytes(terminator, size)))
            self._changed.wait(timeout_s=wake_s - now_s)
            now_s = clock.now_s()

    def discard_input(self) -> None:
        with self._lock:
            self._check()
            self._carry(self.clock.now_s())
            self._rx.clear()

    # ---- the line model (under the lock)

    def _check(self) -> None:
        reason = self.emulator.sim_link_error()
        if reason is not None:
            raise serial.SerialException(f"{self.url}: {reason}")

    def _service(self, now_s: float) -> None:
        self._check()
        self._carry(now_s)  # bytes produced from now on start on a line idle until now
        if now_s >= self._poll_due_s:
            self.emulator.on_poll(now_s)
            self._poll_due_s = self.emulator.next_due_s(now_s)

    def _carry(self, now_s: float) -> None:
        """Move what the line has carried by now_s from the emulator's FIFO to the host's buffer."""
        emu = self.emulator
        pending = emu.tx_pending()
        if pending:
            n = min(pending, int((now_s - self._carried_s) * self._bytes_per_s + CARRY_SLACK_BYTES))
            if n > 0:
                self._rx += emu.take_tx(n)
                self._carried_s += n / self._bytes_per_s
            pending -= max(n, 0)
        if not pending:
            self._carried_s = max(self._carried_s, now_s)  # an idle line saves no capacity

    def _until_bytes(self, terminator: bytes | None, size: int) -> int:
        """How many more bytes the line must carry to hold the first terminator (or `size` bytes): up to its end
        where the emulator's FIFO holds it, else all that is asked for."""
        room = size - len(self._rx)
        if not terminator:
            return room
        keep = len(terminator) - 1  # a terminator may begin in what was carried already
        ahead = bytes(self._rx[max(len(self._rx) - keep, 0) :]) if keep else b""
        end = (ahead + self.emulator.peek_tx(room)).find(terminator)
        return room if end < 0 else end + len(terminator) - len(ahead)

    def _next_s(self, now_s: float, need: int) -> float:
        """When a wait for `need` more bytes should look again: the emulator's next due time, or earlier
        the time by which the line has carried them."""
        due_s = self._poll_due_s
        pending = self.emulator.tx_pending()
        if pending:
            carried_s = self._carried_s + min(need, pending) / self._bytes_per_s
            delivered_s = math.ceil(carried_s / HOST_LATENCY_S) * HOST_LATENCY_S
            due_s = min(due_s, max(delivered_s, carried_s))
        return due_s


_lines: dict[str, SimLine] = {}
_registry_lock = threading.Lock()


def register(name: str, emulator: SimEmulator) -> str:
    """Put `emulator` on the line `sim://<name>`; returns the URL."""
    if not name or any(c in name for c in "/?#:"):
        raise ValueError(f"bad sim:// line name {name!r}")
    with _registry_lock:
        if name in _lines:
            raise ValueError(f"{SCHEME}://{name} is already registered")
        line = _lines[name] = SimLine(name, emulator)
    return line.url


def unregister(name: str) -> None:
    """Take the line off the registry (idempotent); ports already open see the emulator's state."""
    with _registry_lock:
        _lines.pop(name, None)


def line(name: str) -> SimLine:
    with _registry_lock:
        found = _lines.get(name)
    if found is None:
        raise serial.SerialException(errno.ENOENT, f"no emulator on {SCHEME}://{name}")
    return found
