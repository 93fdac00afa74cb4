"""Known-answer wire tests, in the manner of PyMeasure's `expected_protocol`: exact bytes in, exact bytes out.

The bytes of a test come from the protocol description (the driver's docstring, the manual the
emulator follows), written out in the test, never produced by the codec under test; so a codec
that driver and emulator share is still checked against the manual, both ways:

- `scripted_port(transcript)` (and `driver_on(transcript, make)`, a driver opened on it): a real
  pty whose far end plays a transcript of (bytes the driver must write, bytes the device answers).
  The driver opens its path as it would /dev/ttyUSB0. On leaving the block every step must have
  been played with exactly its bytes, and nothing more may have been written (a transcript left
  over or an extra byte fails the test);
- `answers(emulator, data)`: what an emulator sends back for `data`, taken from its `send`;
- `FrozenClock`: station time that stands still (or moves only when told), so that time stamps
  in frames are known answers.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
import tty
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

from station.clock import WallClock, host_clock

STEP_TIMEOUT_S = 2.0  # wall time the far end waits for a driver's command
QUIET_S = 0.05  # after the transcript: a driver writing more within this fails the test
D = TypeVar("D", bound=contextlib.AbstractContextManager)


class FrozenClock:
    """Station time that stands still; `sleep_s` and `advance_s` move it at once (no wall time passes)."""

    def __init__(self, t_s: float = 0.0) -> None:
        self.t_s = float(t_s)

    def now_s(self) -> float:
        return self.t_s

    def sleep_s(self, duration_s: float) -> None:
        self.t_s += max(duration_s, 0.0)

    def advance_s(self, duration_s: float) -> None:
        self.t_s += duration_s

    @property
    def link(self) -> WallClock:
        """Replies are timed on the host's wall clock, as on a wall-paced simulated station."""
        return host_clock()

    def link_s(self, duration_s: float) -> float:
        return duration_s  # an instrument's own wait, granted as that much wall time


def _read_exactly(fd: int, n: int, timeout_s: float) -> bytes:
    got = b""
    deadline = time.monotonic() + timeout_s
    while len(got) < n:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            break
        try:
            got += os.read(fd, n - len(got))
        except OSError:
            break
    return got


def _drain(fd: int, quiet_s: float) -> bytes:
    got = b""
    while select.select([fd], [], [], quiet_s)[0]:
        try:
            chunk = os.read(fd, 4096)
        except OSError:
            break
        if not chunk:
            break
        got += chunk
    return got


@contextlib.contextmanager
def scripted_port(transcript: Sequence[tuple[bytes, bytes]]) -> Iterator[str]:
    """A pty path whose far end plays `transcript`: for each (command, reply) it reads exactly len(command)
    bytes, then writes `reply` (b"": no answer; a command b"": answer at once, unasked)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    received: list[bytes] = []

    def play() -> None:
        for command, reply in transcript:
            got = _read_exactly(master, len(command), STEP_TIMEOUT_S)
            received.append(got)
            if got != command:
                return
            if reply:
                os.write(master, reply)

    player = threading.Thread(target=play, name="scripted-port", daemon=True)
    player.start()
    failed = False
    try:
        yield os.ttyname(slave)
    except BaseException:
        failed = True
        raise
    finally:
        player.join(STEP_TIMEOUT_S * max(len(transcript), 1))
        extra = b"" if failed else _drain(master, QUIET_S)
        os.close(master)
        os.close(slave)
    expected = [command for command, _ in transcript]
    assert received == expected, f"driver wrote {received!r}, the transcript says {expected!r}"
    assert not extra, f"driver wrote {extra!r} after the transcript"


@contextlib.contextmanager
def driver_on(transcript: Sequence[tuple[bytes, bytes]], make: Callable[[str], D]) -> Iterator[D]:
    """`make(port)` opened (as a context manager) on a port that plays `transcript`, and closed again."""
    with scripted_port(transcript) as port, make(port) as driver:
        yield driver


def answers(emulator: Any, data: bytes, *, poll_at_s: float | None = None) -> bytes:
    """The bytes `emulator` sends for `data` (its on_bytes), then for one poll at poll_at_s if given."""
    sent: list[bytes] = []
    emulator.send = lambda data, *_: sent.append(data)  # the instance's send, not the pty's transmit queue
    if data:
        emulator.on_bytes(data)
    if poll_at_s is not None:
        emulator.on_poll(poll_at_s)
    return b"".join(sent)
