"""Temperature chamber (seed 001's heat chamber) whose controller speaks EI-Bisynch ASCII, as Eurotherm 2400s do.

Read     [EOT] G G U U C1 C2 [ENQ]                    (address 01: G = '0', U = '1')
Reply    [STX] C1 C2 <data> [ETX] (BCC)               or [EOT]: no such parameter
Write    [EOT] G G U U [STX] C1 C2 <data> [ETX] (BCC)  reply [ACK], or [NAK]: refused
BCC      XOR of every byte after STX up to and including ETX.

Parameters (two-letter mnemonics):
    PV  product temperature, deg C (`S.br` when the sensor is broken)
    SL  target set point, deg C (read/write)
    SP  working set point, deg C: ramps towards SL at RR
    RR  set-point rate limit, deg C per minute (read/write; 0: steps)
    SW  status word `>XXXX` (hex): bit 0 over-temperature (AL1), 1 under-temperature (AL2),
        2 sensor break, 3 loop break, 4 set point ramping
    AC  write 1: acknowledge latched alarms
    II  instrument identity `>2408`

Errors: no reply -> DeviceTimeout; garbage or a reply cut short -> FrameError; bad BCC ->
ChecksumError; EOT to a read, NAK to a write, an active alarm or a broken sensor -> DeviceFault;
a set point or ramp outside the station's limits -> LimitError (nothing sent); port gone ->
Disconnected. Every command is retried on timeouts and damaged replies: reads have no
effect and writes set absolute values, so repeating one is harmless.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import reduce
from operator import xor
from typing import Any

from devices.config import SerialSection, in_range, spec
from devices.errors import ChecksumError, DeviceFault, DeviceTimeout, DriverError, FrameError, LimitError
from devices.registry import DeviceKind
from devices.serial_port import SerialDevice, with_retries
from station.clock import Clock

DEVICE = "temperature chamber"
STX, ETX, EOT, ENQ, ACK, NAK = b"\x02", b"\x03", b"\x04", b"\x05", b"\x06", b"\x15"
SENSOR_BREAK = "S.br"
ALARM_BITS = {0: "over-temperature (AL1)", 1: "under-temperature (AL2)", 2: "sensor break", 3: "loop break"}
RAMPING_BIT = 4


# ---------------------------------------------------------------- codec


def bcc(data: bytes) -> int:
    """EI-Bisynch block check: XOR of the bytes."""
    return reduce(xor, data, 0)


def address_field(address: int) -> bytes:
    """Group and unit digits, each sent twice: address 1 -> b'0011'."""
    g, u = f"{address:02d}".encode("ascii")
    return bytes((g, g, u, u))


def encode_read(address: int, mnemonic: str) -> bytes:
    return EOT + address_field(address) + mnemonic.encode("ascii") + ENQ


def block(mnemonic: str, data: str) -> bytes:
    """[STX] C1 C2 <data> [ETX] (BCC): a write's body and a read's reply."""
    body = (mnemonic + data).encode("ascii") + ETX
    return STX + body + bytes((bcc(body),))


def encode_write(address: int, mnemonic: str, data: str) -> bytes:
    return EOT + address_field(address) + block(mnemonic, data)


def reply_length(buf: bytes | bytearray) -> int | None:
    """Bytes of the complete reply at the start of `buf`; None if incomplete; FrameError if not a reply."""
    if not buf:
        return None
    first = buf[:1]
    if first in (ACK, NAK, EOT):
        return 1
    if first != STX:
        raise FrameError(DEVICE, f"not a reply: {bytes(buf[:16])!r}")
    end = buf.find(ETX)
    return end + 2 if 0 <= end < len(buf) - 1 else None


def decode_block(frame: bytes, mnemonic: str) -> str:
    """The data of a read's reply to `mnemonic`; typed errors when it is damaged."""
    body = frame[1:-1]
    if frame[-1] != bcc(body):
        raise ChecksumError(DEVICE, f"reply {frame!r}: BCC {frame[-1]:02X} != computed {bcc(body):02X}")
    try:
        text = body[:-1].decode("ascii")
    except UnicodeDecodeError as exc:
        raise FrameError(DEVICE, f"reply {frame!r} is not ASCII") from exc
    if text[:2] != mnemonic:
        raise FrameError(DEVICE, f"reply {frame!r} answers {text[:2]!r}, not {mnemonic!r}")
    return text[2:]


# ---------------------------------------------------------------- configuration


@dataclass(frozen=True)
class TemperatureChamberSection(SerialSection):
    """[temperature_chamber]: the controller's address and the station's limits for the instrument inside."""

    address: int = spec(in_range(0, 99))
    setpoint_min_c: float = spec(in_range(-100.0, 200.0))
    setpoint_max_c: float = spec(in_range(-100.0, 200.0))
    ramp_max_c_per_min: float = spec(in_range(0.0, 20.0, lo_open=True))
    stable_band_c: float = spec(in_range(0.0, 5.0, lo_open=True))  # "at temperature": |PV - SL| within this
    time_constant_s: float = spec(in_range(1.0, 36_000.0))  # product temperature lag, for soak estimates
    timeout_s: float = spec(in_range(0.0, 10.0, lo_open=True))

    def __post_init__(self) -> None:
        if not self.setpoint_min_c < self.setpoint_max_c:
            raise ValueError(
                f"[temperature_chamber] setpoint_min_c = {self.setpoint_min_c!r}: "
                f"not allowed (allowed: < setpoint_max_c = {self.setpoint_max_c!r})"
            )


# ---------------------------------------------------------------- driver


@dataclass(frozen=True)
class ChamberStatus:
    temperature_c: float
    setpoint_c: float
    working_setpoint_c: float
    alarms: tuple[str, ...]
    ramping: bool


class TemperatureChamber(SerialDevice):
    """Driver of the chamber controller; `set_*` refuse values outside the station's limits before sending."""

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 9600,
        address: int = 1,
        setpoint_min_c: float = -40.0,
        setpoint_max_c: float = 80.0,
        ramp_max_c_per_min: float = 5.0,
        stable_band_c: float = 0.1,
        time_constant_s: float = 600.0,  # the product's lag, for soak estimates
        timeout_s: float = 0.5,
        retries: int = 2,
    ) -> None:
        super().__init__(port, baud)
        self.address = address
        self.setpoint_min_c = setpoint_min_c
        self.setpoint_max_c = setpoint_max_c
        self.ramp_max_c_per_min = ramp_max_c_per_min
        self.stable_band_c = stable_band_c
        self.time_constant_s = time_constant_s
        self.timeout_s = timeout_s
        self.retries = retries

    # ---- transactions

    def _exchange(self, message: bytes, what: str) -> bytes:
        """Send one message and return its whole reply (bounded wait)."""
        link = self._link
        if link is None:
            raise DriverError(DEVICE, f"port {self.port} is not open")
        with self._io:
            link.discard_input()
            link.write(message)
            deadline = time.monotonic() + self.timeout_s
            buf = b""
            while (n := reply_length(buf)) is None:
                left = deadline - time.monotonic()
                if left <= 0:
                    if buf:
                        raise FrameError(DEVICE, f"{what}: truncated reply {buf!r} within {self.timeout_s:g} s")
                    raise DeviceTimeout(DEVICE, f"no reply to {what} within {self.timeout_s:g} s")
                buf += link.read_some(left)
            return buf[:n]

    def read(self, mnemonic: str) -> str:
        """A parameter's data (retried)."""

        def once() -> str:
            reply = self._exchange(encode_read(self.address, mnemonic), f"read {mnemonic}")
            if reply == EOT:
                raise DeviceFault(DEVICE, "parameter not known to the controller", field=mnemonic, value=None)
            if reply[:1] != STX:
                raise FrameError(DEVICE, f"read {mnemonic}: reply {reply!r} is not a data block")
            return decode_block(reply, mnemonic)

        return with_retries(once, self.retries)

    def write(self, mnemonic: str, data: str) -> None:
        """Set a parameter (retried: values are absolute); DeviceFault if the controller refuses it."""

        def once() -> None:
            reply = self._exchange(encode_write(self.address, mnemonic, data), f"write {mnemonic} {data}")
            if reply == NAK:
                raise DeviceFault(DEVICE, "write refused by the controller (NAK)", field=mnemonic, value=data)
            if reply != ACK:
                raise FrameError(DEVICE, f"write {mnemonic}: reply {reply!r} is neither ACK nor NAK")

        with_retries(once, self.retries)

    def _number(self, mnemonic: str) -> float:
        data = self.read(mnemonic)
        if data.strip() == SENSOR_BREAK:
            raise DeviceFault(DEVICE, "sensor break", field=mnemonic, value=data, allowed="a temperature")
        try:
            return float(data)
        except ValueError as exc:
            raise FrameError(DEVICE, f"{mnemonic} = {data!r} is not a number") from exc

    # ---- queries

    def identity(self) -> str:
        return self.read("II")

    def temperature_c(self) -> float:
        """The product temperature (PV)."""
        return self._number("PV")

    def setpoint_c(self) -> float:
        return self._number("SL")

    def working_setpoint_c(self) -> float:
        return self._number("SP")

    def ramp_rate_c_per_min(self) -> float:
        return self._number("RR")

    def _status_word(self) -> tuple[tuple[str, ...], bool]:
        """(active alarms, set point ramping) from SW."""
        word = self.read("SW")
        try:
            bits = int(word.lstrip(">"), 16)
        except ValueError as exc:
            raise FrameError(DEVICE, f"status word {word!r} is not >XXXX hex") from exc
        return tuple(name for bit, name in ALARM_BITS.items() if bits >> bit & 1), bool(bits >> RAMPING_BIT & 1)

    def check_alarms(self) -> None:
        """DeviceFault naming the active alarms, if any (one query)."""
        alarms = self._status_word()[0]
        if alarms:
            raise DeviceFault(DEVICE, "alarm active", field="alarms", value=", ".join(alarms), allowed="none")

    def status(self) -> ChamberStatus:
        """Temperature, set points, alarms and ramping (a broken sensor reads NaN here, not an error)."""
        alarms, ramping = self._status_word()
        pv = float("nan") if "sensor break" in alarms else self.temperature_c()
        return ChamberStatus(pv, self.setpoint_c(), self.working_setpoint_c(), alarms, ramping)

    def settled(self, status: ChamberStatus) -> bool:
        """At temperature: the set point has stopped ramping and the product is within the stable band of it."""
        return not status.ramping and abs(status.temperature_c - status.setpoint_c) <= self.stable_band_c

    # ---- commands

    def set_setpoint(self, setpoint_c: float) -> None:
        if not self.setpoint_min_c <= setpoint_c <= self.setpoint_max_c:
            raise LimitError(DEVICE, "set point out of range", field="setpoint_c", value=setpoint_c,
                             allowed=f"{self.setpoint_min_c:g} .. {self.setpoint_max_c:g} deg C")  # fmt: skip
        self.write("SL", f"{setpoint_c:.2f}")

    def set_ramp_rate(self, rate_c_per_min: float) -> None:
        if not 0 < rate_c_per_min <= self.ramp_max_c_per_min:
            raise LimitError(DEVICE, "ramp rate out of range", field="ramp_c_per_min", value=rate_c_per_min,
                             allowed=f"0 < rate <= {self.ramp_max_c_per_min:g} deg C/min")  # fmt: skip
        self.write("RR", f"{rate_c_per_min:.2f}")

    def acknowledge_alarms(self) -> None:
        self.write("AC", "1")


def _open(section: TemperatureChamberSection, clock: Clock) -> TemperatureChamber:
    return TemperatureChamber(
        section.port or "", baud=section.baud, address=section.address, setpoint_min_c=section.setpoint_min_c,
        setpoint_max_c=section.setpoint_max_c, ramp_max_c_per_min=section.ramp_max_c_per_min,
        stable_band_c=section.stable_band_c, time_constant_s=section.time_constant_s, timeout_s=section.timeout_s,
    ).open()  # fmt: skip


def _emulate(section: TemperatureChamberSection, world: Any) -> Any:
    from devices.temperature_chamber.emulator import ChamberEmulator

    emu = ChamberEmulator(world, baud=section.baud, address=section.address, time_constant_s=section.time_constant_s)
    emu.start()
    return emu


DEVICE_KIND = DeviceKind("temperature_chamber", TemperatureChamberSection, _open, _emulate)
