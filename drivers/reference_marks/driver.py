"""Reference marks and frequency monitor (TONiC-like read head with a time-stamping interface).

The interface time-stamps each reference (zero-position) crossing of the
read head, moving up (crank phase psi = 0 mod 2 pi), with a 32-bit counter of
50 ns ticks, and reports the read head's alarm line (signal loss or
overspeed). ASCII lines at 115200 baud, NMEA style: `$` body `*` checksum
CR LF, where the checksum is the XOR of the body's bytes as two upper-case
hex digits. Commands carry a checksum too.

Host -> device
    $START*hh     start reporting (crossing numbers restart at 0)
    $STOP*hh      stop reporting
    $STATUS?*hh   query
Device -> host
    $OK,<cmd>*hh                              command accepted
    $ERR,<reason>*hh                          BADCMD or CHECKSUM
    $ST,<reporting 0/1>,<alarm>,<n>,<ticks>*hh  status (n: crossings so far)
    $Z,<n>,<ticks>*hh                         crossing number n (decimal)
    $H,<ticks>*hh                             heartbeat, every 1 s of station time
    $A,<alarm>,<ticks>*hh                     alarm change: 0 clear, 1 signal loss,
                                              2 overspeed
ticks are 8 hex digits. No crossing is reported while the alarm is active.

Errors: silence (not even a heartbeat) for `silence_s` -> DeviceTimeout; a
line that does not parse or is cut short -> FrameError; checksum mismatch ->
ChecksumError; alarm -> DeviceFault (field "alarm"), raised again at every
heartbeat while it lasts; port gone -> Disconnected. A gap in crossing numbers is counted as
lost crossings (and restarts a frequency measurement). STATUS?/START/STOP
are idempotent and retried.

Frequency stability follows seed 000, section 6.1.2: with f_e = 1 / T_e the
frequencies of 10 consecutive periods and fbar their mean,
sigma_f / f = (1 / (3 fbar)) sqrt(sum (f_e - fbar)^2)  (1/3 = 1/sqrt(10 - 1)).
"""

from __future__ import annotations

import contextlib
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.errors import DeviceFault, DeviceTimeout, DriverError, FrameError
from drivers.reference_marks.protocol import ALARMS, DEVICE, EVENTS, decode_line, encode_line
from drivers.serial_port import SerialDevice, TickUnwrapper, with_retries
from station.clock import Clock
from station.engine.protocols import FrequencyEstimate

# ---------------------------------------------------------------- frequency


def frequency_stability(crossing_times_s: Sequence[float] | np.ndarray) -> FrequencyEstimate:
    """Mean frequency and stability from consecutive crossing times (N+1 times, N periods).

    sigma_f / f = (1 / (sqrt(N - 1) fbar)) sqrt(sum (f_e - fbar)^2), which is the
    seed's (1 / (3 fbar)) sqrt(...) for its N = 10 periods.
    """
    t = np.asarray(crossing_times_s, dtype=float)
    if t.size < 3:
        raise ValueError(f"need at least 3 crossings (2 periods), got {t.size}")
    periods = np.diff(t)
    if np.any(periods <= 0):
        raise ValueError("crossing times must increase")
    f = 1.0 / periods
    fbar = float(f.mean())
    sigma = math.sqrt(float(np.sum((f - fbar) ** 2))) / (math.sqrt(f.size - 1) * fbar)
    return FrequencyEstimate(fbar, sigma, periods)


# ---------------------------------------------------------------- driver


@dataclass(frozen=True, slots=True)
class Crossing:
    n: int  # crossing number since START
    t_s: float  # time stamp (station time when the clock is synchronised)


class ReferenceMarks(SerialDevice):
    """Driver of the reference-mark monitor: crossings, alarms, measured frequency.

    `clock`: if given, the device time base is the station clock's (as in the
    emulator) and time stamps are in station seconds.
    """

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 115_200,
        timeout_s: float = 0.5,
        silence_s: float = 3.0,
        retries: int = 2,
        clock: Clock | None = None,
    ) -> None:
        super().__init__(port, baud, clock=clock)
        self.timeout_s = timeout_s
        self.silence_s = silence_s
        self.retries = retries
        self._unwrap = TickUnwrapper(clock, absolute=clock is not None, sequential=True)
        self._last_n: int | None = None
        self._backlog: deque[bytes] = deque()  # event lines read while awaiting a reply
        self.alarm = 0
        self.lost_crossings = 0
        self.reporting = False

    # ---- port

    def _before_close(self) -> None:
        if self.reporting:
            with contextlib.suppress(DriverError):
                self._command("STOP", retries=0)
        self.reporting = False

    # ---- commands

    def _command(self, cmd: str, *, retries: int | None = None) -> list[str]:
        want = "ST" if cmd == "STATUS?" else "OK"

        def once() -> list[str]:
            self.lines.link.write(encode_line(cmd))
            deadline_s = self._link_clock.now_s() + self.timeout_s
            while True:
                left_s = deadline_s - self._link_clock.now_s()
                if left_s <= 0:
                    raise DeviceTimeout(DEVICE, f"no reply to {cmd} within {self.timeout_s:g} s")
                try:
                    line = self.lines.read_line(left_s)
                    fields = decode_line(line)
                except DeviceTimeout:
                    raise DeviceTimeout(DEVICE, f"no reply to {cmd} within {self.timeout_s:g} s") from None
                except FrameError:
                    continue  # debris of the event stream; the reply may still come
                if fields[0] == "ERR":
                    raise DeviceFault(DEVICE, f"{cmd} rejected: {','.join(fields[1:])}")
                if fields[0] == want and (want == "ST" or fields[1:2] == [cmd]):
                    return fields
                if fields[0] in EVENTS:
                    self._backlog.append(line)  # handed to next_crossing later

        return with_retries(once, self.retries if retries is None else retries)

    def start(self) -> None:
        """Start reporting crossings (numbers restart at 0)."""
        self.lines.link.discard_input()
        self.lines.clear()
        self._backlog.clear()
        self._unwrap.reset()  # before START: the first crossing is stamped after it
        self._command("START")
        self._last_n = None
        self.reporting = True

    def stop(self) -> None:
        self._command("STOP")
        self.reporting = False

    def status(self) -> dict[str, object]:
        """Query (retried): reporting, alarm code, crossings so far, device ticks."""
        f = self._command("STATUS?")
        try:
            return {
                "reporting": f[1] == "1",
                "alarm": int(f[2]),
                "crossings": int(f[3]),
                "ticks": int(f[4], 16),
            }
        except (IndexError, ValueError) as exc:
            raise FrameError(DEVICE, f"malformed status {f!r}") from exc

    # ---- events

    def _alarm_fault(self) -> DeviceFault:
        return DeviceFault(
            DEVICE,
            f"read-head alarm: {ALARMS.get(self.alarm, self.alarm)}",
            field="alarm",
            value=self.alarm,
        )

    def next_crossing(self, timeout_s: float = 15.0) -> Crossing:
        """The next reference crossing, waiting at most timeout_s (link clock).

        Raises DeviceTimeout if the device falls silent for silence_s or no
        crossing comes within timeout_s, DeviceFault while the alarm is active.
        """
        deadline_s = self._link_clock.now_s() + timeout_s
        while True:
            left_s = deadline_s - self._link_clock.now_s()
            if left_s <= 0:
                if self.alarm:
                    raise self._alarm_fault()
                raise DeviceTimeout(DEVICE, f"no reference crossing within {timeout_s:g} s (table at rest?)")
            try:
                line = self._backlog.popleft() if self._backlog else self.lines.read_line(min(left_s, self.silence_s))
            except DeviceTimeout:
                if left_s <= self.silence_s:
                    continue  # the overall deadline decides
                raise DeviceTimeout(DEVICE, f"device silent for {self.silence_s:g} s (no heartbeat)") from None
            fields = decode_line(line)
            kind = fields[0]
            try:
                if kind == "Z":
                    n, raw = int(fields[1]), int(fields[2], 16)
                    t_s = self._unwrap.unwrap_s(raw)
                    if self._last_n is not None and n > self._last_n + 1:
                        self.lost_crossings += n - self._last_n - 1
                    self._last_n = n
                    return Crossing(n, t_s)
                if kind == "H":
                    self._unwrap.unwrap_s(int(fields[1], 16))
                    if self.alarm:
                        raise self._alarm_fault()
                elif kind == "A":
                    self.alarm = int(fields[1])
                    self._unwrap.unwrap_s(int(fields[2], 16))
                    if self.alarm:
                        raise self._alarm_fault()
            except (IndexError, ValueError) as exc:
                raise FrameError(DEVICE, f"malformed event {line!r}") from exc

    def crossings(self, count: int, timeout_s: float = 15.0) -> list[Crossing]:
        """`count` crossings (each within timeout_s of the previous)."""
        return [self.next_crossing(timeout_s) for _ in range(count)]

    def measure_frequency(self, periods: int = 10, timeout_s: float = 15.0) -> FrequencyEstimate:
        """Frequency and stability over `periods` consecutive periods (restarts on a gap)."""
        run: list[Crossing] = []
        while len(run) < periods + 1:
            c = self.next_crossing(timeout_s)
            if run and c.n != run[-1].n + 1:
                run = []
            run.append(c)
        return frequency_stability([c.t_s for c in run])
