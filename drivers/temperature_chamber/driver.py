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

Errors: no reply -> DeviceTimeout; garbage (let pass until the line is quiet, so that the retry reads its own
reply) or a reply cut short -> FrameError; bad BCC ->
ChecksumError; EOT to a read, NAK to a write, an active alarm or a broken sensor -> DeviceFault;
a set point or ramp outside the station's limits -> LimitError (nothing sent); port gone ->
Disconnected. Every command is retried on timeouts and damaged replies: reads have no
effect and writes set absolute values, so repeating one is harmless.
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.errors import DeviceFault, DeviceTimeout, DriverError, FrameError, LimitError
from drivers.serial_port import SerialDevice, with_retries
from drivers.temperature_chamber.protocol import (
    ACK,
    ALARM_BITS,
    DEVICE,
    EOT,
    NAK,
    RAMPING_BIT,
    SENSOR_BREAK,
    STX,
    decode_block,
    encode_read,
    encode_write,
    reply_length,
)
from station.clock import Clock


@dataclass(frozen=True)
class ChamberStatus:
    temperature_c: float
    setpoint_c: float
    working_setpoint_c: float
    alarms: tuple[str, ...]
    ramping: bool


class TemperatureChamber(SerialDevice):
    """Driver of the chamber controller; `set_*` refuse values outside the station's limits before sending.

    `clock`, the station clock, only times the replies (its link clock).
    """

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
        clock: Clock | None = None,
    ) -> None:
        super().__init__(port, baud, clock=clock)
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
            deadline_s = self._link_clock.now_s() + self.timeout_s
            buf = b""
            while True:
                try:
                    n = reply_length(buf)
                except FrameError:
                    # Not a reply: the rest of it is still on the line and would spoil the retry's reply.
                    link.discard_until_quiet(deadline_s - self._link_clock.now_s())
                    raise
                if n is not None:
                    return buf[:n]
                left_s = deadline_s - self._link_clock.now_s()
                if left_s <= 0:
                    if buf:
                        raise FrameError(DEVICE, f"{what}: truncated reply {buf!r} within {self.timeout_s:g} s")
                    raise DeviceTimeout(DEVICE, f"no reply to {what} within {self.timeout_s:g} s")
                buf += link.read_some(left_s)

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
