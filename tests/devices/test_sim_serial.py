"""The sim:// pyserial URL handler (drivers.sim_serial): a line to an emulator called in the port user's thread.

The emulators run on a VirtualClock 100 times faster than the wall clock, so that
station seconds and wall seconds differ: every assertion on time is in station
seconds of that clock, except where a bound shows that a wait did not count wall
seconds (then the margin is the factor 100, stated).
"""

from __future__ import annotations

import errno
import threading
import time
from collections.abc import Iterator

import pytest
import serial

from drivers import sim_serial
from drivers.errors import Disconnected, DriverError
from drivers.pty_link import Fault, PtyEmulator
from drivers.serial_port import SerialLink
from station.clock import VirtualClock
from station.event_clock import EventClock

pytestmark = pytest.mark.timeout(60)

SPEED = 100.0  # station seconds per wall second
BAUD = 9600  # 960 bytes per station second


class EchoEmulator(PtyEmulator):
    """Answers each command line with `OK <line>`; `blob <n>` answers n bytes."""

    name = "echo"

    def __init__(self, clock: VirtualClock) -> None:
        super().__init__(clock, baud=BAUD)
        self.threads: list[threading.Thread] = []

    def on_bytes(self, data: bytes) -> None:
        self.threads.append(threading.current_thread())
        for line in self.command_lines(data):
            if line.startswith(b"blob "):
                self.send(b"x" * int(line[5:]))
            else:
                self.send(b"OK " + line + b"\n")


@pytest.fixture
def echo() -> Iterator[tuple[EchoEmulator, str]]:
    emu = EchoEmulator(VirtualClock(SPEED))
    url = emu.start_sim()
    try:
        yield emu, url
    finally:
        emu.close()


def _open(url: str, timeout_s: float | None = 5.0) -> serial.SerialBase:
    return serial.serial_for_url(url, BAUD, timeout=timeout_s, exclusive=True)


def test_a_command_round_trip_in_the_writers_thread(echo) -> None:
    emu, url = echo
    assert url.startswith("sim://echo-")
    port = _open(url)
    try:
        port.write(b"status\n")
        assert emu.threads == [threading.current_thread()]  # handed over at once, no thread of its own
        assert port.read_until(b"\n") == b"OK status\n"
        assert port.in_waiting == 0
    finally:
        port.close()


def test_bytes_arrive_at_the_baud_rate_in_station_time(echo) -> None:
    emu, url = echo
    clock = emu.clock
    port = _open(url)
    try:
        t_sent_s = clock.now_s()
        port.write(b"blob 960\n")
        t_written_s = clock.now_s()
        clock.sleep_s(0.25)
        t_before_s = clock.now_s()
        n = port.in_waiting
        t_after_s = clock.now_s()
        # what 960 bytes/s carries between the reply's creation and the look, one byte of rounding either way
        assert (t_before_s - t_written_s) * 960 - 1 <= n <= (t_after_s - t_sent_s) * 960 + 1
        assert n < 960
        data = port.read(960)
        t_done_s = clock.now_s()
        assert data == b"x" * 960
        assert t_done_s - t_sent_s >= 959 / 960  # the last byte is carried one second after the first starts
    finally:
        port.close()


def test_a_read_times_out_in_station_seconds(echo) -> None:
    emu, url = echo
    clock = emu.clock
    port = _open(url, timeout_s=2.0)
    try:
        emu.inject(Fault.NO_ANSWER)
        t0_s, wall0_s = clock.now_s(), time.monotonic()
        port.write(b"status\n")
        assert port.read(1) == b""  # the command was swallowed
        assert clock.now_s() - t0_s >= 2.0
        assert time.monotonic() - wall0_s < 2.0  # 0.02 s of wall time: counted in wall seconds it would be 2 s
        port.write(b"status\n")
        assert port.read_until(b"\n") == b"OK status\n"  # one command swallowed, the next answered
    finally:
        port.close()


def test_an_exclusive_port_is_in_use_for_a_second_opener(echo) -> None:
    _, url = echo
    first = _open(url)
    with pytest.raises(serial.SerialException) as info:
        _open(url)
    assert info.value.errno == errno.EBUSY
    with pytest.raises(DriverError, match="in use"):
        SerialLink("echo", url, BAUD)
    first.close()
    _open(url).close()  # free again


@pytest.mark.parametrize("how", ["disconnect", "fault", "close"])
def test_a_pulled_cable_or_closed_emulator_fails_every_call(echo, how) -> None:
    emu, url = echo
    link = SerialLink("echo", url, BAUD, clock=emu.clock)
    link.write(b"status\n")
    assert link.read_some(1.0).startswith(b"O")
    if how == "disconnect":
        emu.disconnect()
    elif how == "fault":
        emu.inject(Fault.DISCONNECT)
    else:
        emu.close()
    with pytest.raises(Disconnected):
        link.read_some(1.0)
    with pytest.raises(Disconnected):
        link.write(b"status\n")
    link.close()
    with pytest.raises(Disconnected, match="cannot open"):
        SerialLink("echo", url, BAUD)


class QuietEmulator(EchoEmulator):
    """Never due by itself (as a meter between readings, a head between commands): only a write polls it."""

    def next_due_s(self, now_s: float) -> float:
        return float("inf")


@pytest.mark.parametrize("how", ["disconnect", "fault", "close"])
def test_a_reader_waiting_on_an_emulator_never_due_sees_the_failure_at_once(how) -> None:
    """On the discrete-event clock nothing wakes such a reader before its 10 s timeout but the failure itself:
    it must raise at the station time the cable is pulled (0.5 s), not at the timeout."""
    clock = EventClock()
    emu = QuietEmulator(clock)  # type: ignore[arg-type]
    url = emu.start_sim()
    failures = {"disconnect": emu.disconnect, "fault": lambda: emu.inject(Fault.DISCONNECT), "close": emu.close}
    try:
        with clock.party("reader"):
            link = SerialLink("echo", url, BAUD, clock=clock)
            clock.call_at(0.5, failures[how])
            with pytest.raises(Disconnected):
                link.read_some(10.0)
            assert clock.now_s() == 0.5
            link.close()
    finally:
        emu.close()


def test_unknown_lines_and_names() -> None:
    with pytest.raises(serial.SerialException, match="no emulator"):
        serial.serial_for_url("sim://nobody")
    emu = EchoEmulator(VirtualClock(SPEED))
    url = emu.start_sim("echo-named")
    try:
        assert url == "sim://echo-named"
        with pytest.raises(ValueError, match="already registered"):
            sim_serial.register("echo-named", emu)
        with pytest.raises(RuntimeError, match="already started"):
            emu.start()
    finally:
        emu.close()
    with pytest.raises(serial.SerialException, match="no emulator"):
        serial.serial_for_url(url)
