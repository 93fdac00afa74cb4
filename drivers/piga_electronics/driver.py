"""PIGA electronics: the instrument's circuit board and its angle servo with a digital offset (seed 004 Figs. 1c, 6b).

The board holds the inner frame's angle beta with a PID loop on the angle encoder; a digital offset dbeta is
added to the encoder reading, so the servo holds beta = beta0 + dbeta (seed 004 section 5.1). The station sets
dbeta over a serial line in a SCPI-like ASCII protocol with an XOR checksum (NMEA style), 115200 baud 8N1:

    command  <body>*<cs>\\n          reply  <body>*<cs>\\r\\n
    cs: XOR of the body's bytes, two upper-case hex digits. Every command gets exactly one reply.

    *IDN?               -> <maker>,<model>,<serial>,<firmware>
    SERV:OFFS <arcsec>  -> OK                set dbeta in arc-seconds (at most 3 decimals)
    SERV:OFFS?          -> <arcsec>          the offset in force, e.g. -0.850
    SERV:STAT?          -> <state>,<err>     LOCK, SETTLE or FAULT; err: beta minus its setpoint, arc-seconds
    SYST:ERR?           -> <code>,"<text>"   the oldest queued error; 0,"No error"
    *CLS                -> OK                clear the error queue and a latched servo fault (it re-acquires)
    rejected            -> ERR <code>,"<text>"
        -100 unknown command, -104 data type, -222 data out of range, -310 bad checksum,
        301 servo fault latched (the servo lost lock; *CLS)

After an offset change, and after *CLS clears a fault, the servo reports SETTLE until beta has followed, then LOCK.

Errors: no reply -> DeviceTimeout; a reply cut short (no line end) or malformed -> FrameError; a wrong
checksum -> ChecksumError; ERR replies and a FAULT state -> DeviceFault (field "reply" or "servo");
an offset beyond +-offset_max_arcsec -> LimitError (nothing sent); port gone -> Disconnected. Queries and
SERV:OFFS (an absolute setpoint, so repeating it is harmless) are retried; the offset is read back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.errors import DeviceFault, DeviceTimeout, FrameError, LimitError
from drivers.piga_electronics.protocol import DEVICE, OFFSET_DECIMALS, SERVO_STATES, decode_line, encode_line
from drivers.serial_port import SerialDevice, with_retries
from station.clock import Clock, WallClock


@dataclass(frozen=True)
class ServoStatus:
    state: str  # LOCK, SETTLE or FAULT
    beta_error_arcsec: float


class PigaElectronics(SerialDevice):
    """Driver of the PIGA's electronics: identity, angle-servo offset and state."""

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 115_200,
        offset_max_arcsec: float = 10.0,
        lock_timeout_s: float = 60.0,
        timeout_s: float = 0.5,
        retries: int = 2,
        poll_s: float = 0.2,
        clock: Clock | None = None,
    ) -> None:
        super().__init__(port, baud, clock=clock)
        self.offset_max_arcsec = offset_max_arcsec
        self.lock_timeout_s = lock_timeout_s
        self.timeout_s = timeout_s
        self.retries = retries
        self.poll_s = poll_s
        self.clock: Clock = clock if clock is not None else WallClock()

    # ---- transactions

    def _transact(self, command: str) -> str:
        """One command and its reply body; ERR replies raise DeviceFault."""
        lines = self.lines
        with self._io:
            lines.link.write(encode_line(command) + b"\n")
            try:
                reply = decode_line(lines.read_line(self.timeout_s))
            except DeviceTimeout:
                raise DeviceTimeout(DEVICE, f"no reply to {command!r} within {self.timeout_s:g} s") from None
        if reply.startswith("ERR "):
            raise DeviceFault(DEVICE, f"{command!r} rejected", field="reply", value=reply[4:])
        return reply

    def _retried(self, command: str) -> str:
        def flush() -> None:
            if self._lines is not None:
                self._lines.clear()
                self._lines.link.discard_input()

        return with_retries(lambda: self._transact(command), self.retries, before_retry=flush)

    # ---- queries

    def identify(self) -> str:
        return self._retried("*IDN?")

    def offset_arcsec(self) -> float:
        """The digital offset in force (arc-seconds)."""
        reply = self._retried("SERV:OFFS?")
        try:
            return float(reply)
        except ValueError:
            raise FrameError(DEVICE, f"offset {reply!r} is not a number") from None

    def servo_status(self) -> ServoStatus:
        reply = self._retried("SERV:STAT?")
        state, _, err = reply.partition(",")
        try:
            error_arcsec = float(err)
        except ValueError:
            raise FrameError(DEVICE, f"servo status {reply!r}: error {err!r} is not a number") from None
        if state not in SERVO_STATES:
            raise FrameError(DEVICE, f"servo status {reply!r}: state {state!r} not one of {', '.join(SERVO_STATES)}")
        return ServoStatus(state, error_arcsec)

    def clear_fault(self) -> None:
        """Clear the error queue and a latched servo fault (*CLS)."""
        self._retried("*CLS")

    # ---- the offset

    def set_offset_arcsec(self, offset_arcsec: float) -> float:
        """Set dbeta (arc-seconds, rounded to 0.001") and read it back; the offset in force."""
        limit = self.offset_max_arcsec
        if not (math.isfinite(offset_arcsec) and abs(offset_arcsec) <= limit):
            raise LimitError(
                DEVICE,
                "offset out of range",
                field="offset_arcsec",
                value=offset_arcsec,
                allowed=f"-{limit:g} .. {limit:g} arc-seconds",
            )
        target = round(offset_arcsec, OFFSET_DECIMALS)
        self._retried(f"SERV:OFFS {target:.{OFFSET_DECIMALS}f}")
        readback = self.offset_arcsec()
        if abs(readback - target) > 0.5 * 10**-OFFSET_DECIMALS:
            raise DeviceFault(
                DEVICE,
                f"offset read back as {readback:g} after setting {target:g}",
                field="offset_arcsec",
                value=readback,
            )
        return readback

    def wait_locked(self, timeout_s: float | None = None) -> ServoStatus:
        """Poll until the servo reports LOCK (station time); DeviceFault on FAULT, DeviceTimeout after timeout_s."""
        limit = self.lock_timeout_s if timeout_s is None else timeout_s
        t0 = self.clock.now_s()
        while True:
            status = self.servo_status()
            if status.state == "LOCK":
                return status
            if status.state == "FAULT":
                raise DeviceFault(
                    DEVICE, "angle servo lost lock (clear_fault() re-acquires it)", field="servo", value=status.state
                )
            if self.clock.now_s() - t0 > limit:
                raise DeviceTimeout(
                    DEVICE,
                    f"angle servo not locked within {limit:g} s "
                    f"(state {status.state}, beta error {status.beta_error_arcsec:g} arcsec)",
                )
            self.clock.sleep_s(self.poll_s)
