"""Emulator of the temperature chamber's controller (protocol in drivers.temperature_chamber.protocol).

The chamber's physics is one model per world, `world.shared("temperature_chamber", ...)`, so
that the voltmeter's accelerometer sits at the same temperature: the working set point ramps
from where it is to the target at the rate limit, and the product temperature follows it as a
first-order lag (station.twin.chamber_thermal). PV is the product temperature with
0.01 deg C of sensor noise, quoted to 0.01 deg C.

Alarms latch until acknowledged (AC) and their cause is gone: over-temperature when PV exceeds
`alarm_high_c`, under-temperature below `alarm_low_c`. Set points outside the controller's own
range [`sl_min_c`, `sl_max_c`] and rates outside [0, 99.9] deg C/min are refused (NAK).

Faults: NO_ANSWER (ignore `count` commands), GARBLE / TRUNCATE / CRC_ERROR (next data reply),
DISCONNECT, and ChamberFault.SENSOR_BREAK (while armed PV reads `S.br`, status bit 2),
ChamberFault.OVER_TEMPERATURE (the over-temperature protection trips at the next poll).
"""

from __future__ import annotations

import bisect
import enum
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.pty_link import Fault, PtyEmulator, garble, truncate
from drivers.temperature_chamber import protocol as tc
from station.twin.chamber_thermal import ramped_lag

AMBIENT_C = 20.0
PV_NOISE_C = 0.01
RR_MAX_C_PER_MIN = 99.9


class ChamberFault(enum.Enum):
    SENSOR_BREAK = "sensor_break"
    OVER_TEMPERATURE = "over_temperature"


@dataclass(frozen=True)
class _Segment:
    """The chamber from one command to the next: ramp from_c -> target_c at rate, product at start_c at t0_s."""

    t0_s: float
    start_c: float
    from_c: float
    target_c: float
    rate_c_per_min: float


class ChamberThermal:
    """The chamber's product temperature over station time, past ones included (thread-safe); starts at ambient."""

    def __init__(self, ambient_c: float = AMBIENT_C, time_constant_s: float = 600.0) -> None:
        self.time_constant_s = time_constant_s
        self._lock = threading.Lock()
        self._segments = [_Segment(0.0, ambient_c, ambient_c, ambient_c, 0.0)]

    @property
    def target_c(self) -> float:
        return self._segments[-1].target_c

    @property
    def rate_c_per_min(self) -> float:
        return self._segments[-1].rate_c_per_min

    def temperature_c(self, t_s: float) -> float:
        return self.state(t_s)[0]

    def state(self, t_s: float) -> tuple[float, float]:
        """(product temperature, working set point) at station time t_s."""
        with self._lock:
            seg = self._segments[max(bisect.bisect_right([g.t0_s for g in self._segments], t_s) - 1, 0)]
        product, sp = ramped_lag(max(t_s - seg.t0_s, 0.0), seg.start_c, seg.from_c, seg.target_c,
                                 seg.rate_c_per_min / 60.0, self.time_constant_s)  # fmt: skip
        return float(product), float(sp)

    def command(self, t_s: float, target_c: float | None = None, rate_c_per_min: float | None = None) -> None:
        """A new target and/or rate from t_s on; the ramp restarts from where the working set point is."""
        product, sp = self.state(t_s)
        with self._lock:
            last = self._segments[-1]
            target = last.target_c if target_c is None else target_c
            rate = last.rate_c_per_min if rate_c_per_min is None else rate_c_per_min
            self._segments.append(_Segment(t_s, product, sp, target, rate))


class ChamberEmulator(PtyEmulator):
    name = "chamber-emulator"
    supported_faults = frozenset({Fault.NO_ANSWER, Fault.GARBLE, Fault.TRUNCATE, Fault.CRC_ERROR, Fault.DISCONNECT,
                                  ChamberFault.SENSOR_BREAK, ChamberFault.OVER_TEMPERATURE})  # fmt: skip

    def __init__(
        self,
        world: Any,
        *,
        baud: int = 9600,
        address: int = 1,
        time_constant_s: float = 600.0,
        sl_min_c: float = -70.0,
        sl_max_c: float = 180.0,
        alarm_high_c: float = 185.0,
        alarm_low_c: float = -75.0,
        **kw: Any,
    ) -> None:
        super().__init__(world.clock, baud=baud, **kw)
        self.world = world
        self.thermal: ChamberThermal = world.shared("temperature_chamber", lambda: ChamberThermal(
            time_constant_s=time_constant_s))  # fmt: skip
        self.address = tc.address_field(address)
        self.sl_limits_c = (sl_min_c, sl_max_c)
        self.alarm_limits_c = (alarm_low_c, alarm_high_c)
        self.latched: set[int] = set()  # alarm bits
        self.rng = np.random.default_rng(world.rng.integers(2**63))
        self._rx = bytearray()
        self.commands: list[str] = []  # log of received mnemonics (and written data), for tests

    # ---- input

    def on_bytes(self, data: bytes) -> None:
        self._rx += data
        while (i := self._rx.find(tc.EOT)) >= 0:
            del self._rx[:i]
            message = tc.take_message(self._rx)
            if message is None:
                break
            if message[0] == self.address and not self.faults.take(Fault.NO_ANSWER):
                self._handle(*message[1:])
        if len(self._rx) > 512:
            self._rx.clear()

    # ---- protocol

    def _handle(self, mnemonic: str, data: str | None, bcc_ok: bool) -> None:
        self.commands.append(mnemonic if data is None else f"{mnemonic} {data}")
        now = self.clock.now_s()
        if data is None:
            value = self._read(mnemonic, now)
            self._reply(tc.EOT if value is None else tc.block(mnemonic, value))
        else:
            self._reply(tc.ACK if bcc_ok and self._write(mnemonic, data, now) else tc.NAK)

    def _pv_c(self, now: float) -> float:
        return round(self.thermal.temperature_c(now) + self.rng.normal(0.0, PV_NOISE_C), 2)

    def _read(self, mnemonic: str, now: float) -> str | None:
        sp = self.thermal.state(now)[1]
        match mnemonic:
            case "PV":
                return tc.SENSOR_BREAK if self.faults.active(ChamberFault.SENSOR_BREAK) else f"{self._pv_c(now):.2f}"
            case "SL":
                return f"{self.thermal.target_c:.2f}"
            case "SP":
                return f"{sp:.2f}"
            case "RR":
                return f"{self.thermal.rate_c_per_min:.2f}"
            case "SW":
                return f">{self._status_bits(sp):04X}"
            case "II":
                return ">2408"
        return None

    def _status_bits(self, working_sp_c: float) -> int:
        bits = sum(1 << b for b in self.latched)
        if self.faults.active(ChamberFault.SENSOR_BREAK):
            bits |= 1 << 2
        if abs(working_sp_c - self.thermal.target_c) > 1e-9:
            bits |= 1 << tc.RAMPING_BIT
        return bits

    def _write(self, mnemonic: str, data: str, now: float) -> bool:
        try:
            value = float(data)
        except ValueError:
            return False
        match mnemonic:
            case "SL" if self.sl_limits_c[0] <= value <= self.sl_limits_c[1]:
                self.thermal.command(now, target_c=value)
            case "RR" if 0.0 <= value <= RR_MAX_C_PER_MIN:
                self.thermal.command(now, rate_c_per_min=value)
            case "AC":
                self.latched.clear()
                self.on_poll(now)  # alarms whose cause remains latch again at once
            case _:
                return False
        return True

    def _reply(self, message: bytes) -> None:
        if message[:1] == tc.STX:
            if self.faults.take(Fault.GARBLE):
                message = garble(message)
            elif self.faults.take(Fault.TRUNCATE):
                message = truncate(message)
            elif self.faults.take(Fault.CRC_ERROR):
                message = message[:-1] + bytes((message[-1] ^ 0x5A,))
        self.send(message)

    def on_poll(self, now_s: float) -> None:
        if self.faults.take(ChamberFault.OVER_TEMPERATURE):
            self.latched.add(0)
        product = self.thermal.temperature_c(now_s)
        low, high = self.alarm_limits_c
        if product > high:
            self.latched.add(0)
        elif product < low:
            self.latched.add(1)
