"""Precision DC voltmeter (seed 001's "precision multichannel voltmeter", 0.003 %) speaking SCPI over RS-232,
in the style of an 8.5-digit DMM such as the Keithley 2002.

Commands end in LF; a query answers one line.
    *IDN?  *RST  *CLS               identity; reset to 20 V, 1 PLC, 1 sample; clear the error queue
    :CONF:VOLT:DC                   DC volts
    :SENS:VOLT:DC:RANG <v> (?)      range 0.2, 2, 20, 200 or 1000 V; readings to 105 % of it
    :SENS:VOLT:DC:NPLC <n> (?)      aperture, 0.01 .. 50 power-line cycles
    :SAMP:COUN <n> (?)              readings per trigger, 1 .. 1024
    :READ?                          trigger; the readings, comma-separated, NR3 (+1.23456789E+00)
    :SYST:ERR?                      oldest error `<code>,"<text>"`; `0,"No error"` when none
Long forms (`:SENSe:VOLTage:DC:NPLCycles`) are accepted too. An overloaded input reads +9.9E37.
Each reading takes 2 NPLC line periods (auto-zero measures the reference every conversion).

Errors: no reply -> DeviceTimeout; a reply that is not the expected number of NR3 readings, or
cut short -> FrameError; overload or an error in the queue after configuring -> DeviceFault; a
range, NPLC or count the instrument does not have -> LimitError (nothing sent); port gone ->
Disconnected. SCPI has no checksum: damaged replies are caught by their strict format. Queries
are retried (READ? measures again, which is harmless); settings are checked through SYST:ERR?.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from drivers.errors import DeviceFault, DriverError, FrameError, LimitError
from drivers.serial_port import SerialDevice, with_retries
from drivers.voltmeter.protocol import (
    DEVICE,
    MAX_SAMPLES,
    NPLC_LIMITS,
    OVERLOAD_V,
    OVERRANGE,
    RANGES_V,
    parse_readings,
    reading_s,
)
from station.clock import Clock, WallClock

T = TypeVar("T")


@dataclass(frozen=True)
class Reading:
    """One triggered READ?: the readings and the station-time interval they were taken in."""

    volts: np.ndarray
    start_s: float
    end_s: float


class Voltmeter(SerialDevice):
    """Driver of the DMM; `configure` refuses what the instrument does not have before sending."""

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 19_200,
        line_hz: float = 50.0,
        timeout_s: float = 1.0,
        retries: int = 2,
        clock: Clock | None = None,
    ) -> None:
        super().__init__(port, baud, clock=clock)
        self.line_hz = line_hz
        self.timeout_s = timeout_s
        self.retries = retries
        self.clock: Clock = clock if clock is not None else WallClock()
        self._setting: tuple[float, float, int] | None = None  # (range, nplc, samples) in force

    # ---- transactions

    def send(self, command: str) -> None:
        """A command without a reply."""
        with self._io:
            self.lines.link.write(command.encode("ascii") + b"\n")

    def query(self, command: str, parse: Callable[[bytes], T] = bytes, *, wait_s: float = 0.0) -> T:  # type: ignore[assignment]
        """A query's reply line through `parse` (both retried); `wait_s`: station time the instrument needs first."""
        lines = self.lines
        timeout_s = self.timeout_s + self.clock.link_s(wait_s)

        def once() -> T:
            with self._io:
                lines.link.discard_input()
                lines.clear()
                lines.link.write(command.encode("ascii") + b"\n")
                return parse(lines.read_line(timeout_s))

        return with_retries(once, self.retries)

    # ---- instrument

    def identity(self) -> str:
        return self.query("*IDN?").decode("ascii", "replace")

    def errors(self) -> list[str]:
        """Empty the error queue; the errors it held, oldest first."""
        found: list[str] = []
        for _ in range(32):
            entry = self.query(":SYST:ERR?", bytes).decode("ascii", "replace")
            if entry.split(",", 1)[0].strip() in ("0", "+0"):
                return found
            found.append(entry)
        raise FrameError(DEVICE, f"error queue does not empty: {found[-3:]}")

    def configure(self, range_v: float, nplc: float, samples: int) -> None:
        """DC volts on `range_v`, `nplc` power-line cycles, `samples` readings per READ?; DeviceFault if refused."""
        if range_v not in RANGES_V:
            raise LimitError(DEVICE, "no such range", field="range_v", value=range_v,
                             allowed=", ".join(f"{r:g}" for r in RANGES_V) + " V")  # fmt: skip
        if not NPLC_LIMITS[0] <= nplc <= NPLC_LIMITS[1]:
            raise LimitError(DEVICE, "aperture out of range", field="nplc", value=nplc,
                             allowed=f"{NPLC_LIMITS[0]:g} .. {NPLC_LIMITS[1]:g} power-line cycles")  # fmt: skip
        if not (isinstance(samples, int) and 1 <= samples <= MAX_SAMPLES):
            raise LimitError(DEVICE, "sample count out of range", field="samples", value=samples,
                             allowed=f"a whole number 1 .. {MAX_SAMPLES}")  # fmt: skip
        self._setting = None
        self.errors()
        for command in (":CONF:VOLT:DC", f":SENS:VOLT:DC:RANG {range_v:g}", f":SENS:VOLT:DC:NPLC {nplc:g}",
                        f":SAMP:COUN {samples}"):  # fmt: skip
            self.send(command)
        refused = self.errors()
        if refused:
            raise DeviceFault(DEVICE, "configuration refused", field="error queue", value="; ".join(refused))
        self._setting = (range_v, nplc, samples)

    def read(self) -> Reading:
        """Trigger one READ? with the configuration in force."""
        if self._setting is None:
            raise DriverError(DEVICE, "read before configure()")
        range_v, nplc, samples = self._setting
        start_s = self.clock.now_s()
        volts = self.query(":READ?", lambda line: parse_readings(line, samples),
                           wait_s=reading_s(nplc, samples, self.line_hz))  # fmt: skip
        if np.any(np.abs(volts) >= OVERLOAD_V):
            raise DeviceFault(DEVICE, "input overload", field="reading", value=float(np.max(np.abs(volts))),
                              allowed=f"within +-{OVERRANGE * range_v:g} V on the {range_v:g} V range")  # fmt: skip
        return Reading(volts, start_s, self.clock.now_s())

    def measure(self, range_v: float, nplc: float, samples: int) -> Reading:
        """configure() if the setting changed, then read()."""
        if self._setting != (range_v, nplc, samples):
            self.configure(range_v, nplc, samples)
        return self.read()
