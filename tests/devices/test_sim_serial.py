"""The sim:// pyserial URL handler (drivers.sim_serial): a line to an emulator called in the port user's thread.

The emulators run on a VirtualClock 100 times faster than the wall clock, so that
station seconds and wall seconds differ: every assertion on time is in station
seconds of that clock, except where a bound shows that a wait did not count wall
seconds (then the margin is the factor 100, stated).
"""

from __future__ import annotations

import errno
import math
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
    """Answers each command line with `OK <line>`; `blob <n>` answers n bytes, `crlf <text>` `OK <text>` and CR LF."""

    name = "echo"

    def __init__(self, clock: VirtualClock) -> None:
        super().__init__(clock, baud=BAUD)
        self.threads: list[threading.Thread] = []

    def on_bytes(self, data: bytes) -> None:
        self.threads.append(threading.current_thread())
        for line in self.command_lines(data):
            if line.startswith(b"blob "):
                self.send(b"x" * int(line[5:]))
            elif line.startswith(b"crlf "):
                self.send(b"OK " + line[5:] + b"\r\n")
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


@pytest.fixture
def event_port() -> Iterator[tuple[EventClock, serial.SerialBase, list[float]]]:
    """A port (2 s timeout) on an echo emulator never due by itself, on the
    discrete-event clock, and the station times at which a reader of its line woke."""
    clock = EventClock()
    emu = QuietEmulator(clock)  # type: ignore[arg-type]
    url = emu.start_sim()
    line = sim_serial.line(url.removeprefix("sim://"))
    wakes: list[float] = []
    wait = line._changed.wait

    def counted(timeout_s: float | None = None) -> bool:
        woke = wait(timeout_s=timeout_s)
        wakes.append(clock.now_s())
        return woke

    line._changed.wait = counted  # type: ignore[method-assign]
    try:
        with clock.party("reader"):
            port = serial.serial_for_url(url, BAUD, timeout=2.0)
            yield clock, port, wakes
            port.close()
    finally:
        emu.close()


def _delivered_s(carried_s: float) -> float:
    """When the adapter hands over a byte the line has carried at carried_s: the next 1 ms USB frame."""
    return math.ceil(carried_s / sim_serial.HOST_LATENCY_S) * sim_serial.HOST_LATENCY_S


def test_a_line_is_read_with_one_wake_when_its_terminator_has_come(event_port) -> None:
    """read_until (pyserial's readline API) returns at the USB frame that brings the terminator, as a reader of
    single bytes would, but wakes once and not once per frame: at 960 bytes/s a frame brings about one byte."""
    clock, port, wakes = event_port
    port.write(b"status\n")  # answered with "OK status\n", 10 bytes, at station time 0
    assert port.read_until(b"\n") == b"OK status\n"
    assert clock.now_s() == _delivered_s(10 / 960)
    assert wakes == [clock.now_s()]
    wakes.clear()
    port.write(b"again\n")
    t0_s = clock.now_s()
    by_bytes = port.read(1)  # the way a byte reader waits: a wake per frame
    while not by_bytes.endswith(b"\n"):
        by_bytes += port.read(max(port.in_waiting, 1))
    assert by_bytes == b"OK again\n"
    assert clock.now_s() == _delivered_s(t0_s + 9 / 960)  # the same station time as one wake gives
    assert len(wakes) == 9


def test_a_terminator_begun_in_what_was_carried_ends_the_wait_at_its_last_byte(event_port) -> None:
    clock, port, wakes = event_port
    port.write(b"crlf a\n")  # "OK a\r\n": 6 bytes; wait until the line has carried the first five
    clock.sleep_s(5.5 / 960)
    assert port.in_waiting == 5
    assert port.read_until(b"\r\n") == b"OK a\r\n"
    assert clock.now_s() == _delivered_s(6 / 960)
    assert wakes == [clock.now_s()]


def test_read_until_stops_at_its_size_or_its_timeout(event_port) -> None:
    clock, port, _ = event_port
    port.write(b"blob 960\n")  # 960 bytes and no line end: the last is carried after one second
    assert port.read_until(b"\n", 10) == b"x" * 10
    assert clock.now_s() == _delivered_s(10 / 960)
    assert port.read_until(b"\n") == b"x" * 950  # all of it, at the port's timeout
    assert clock.now_s() == pytest.approx(_delivered_s(10 / 960) + 2.0, abs=1e-12)


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
