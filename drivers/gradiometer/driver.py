"""Electronic gradiometer: a precision tilt meter on the table top (seed 000 6.1.3; 0.005" resolution).

ASCII over RS-232 in the manner of electronic levels and inclinometers: the host
addresses one instrument on the line and polls it; each request is answered by one
line; angles are in arc-seconds. Every line carries a checksum, so a damaged reply
is caught instead of read as a tilt.

Request  `#<aa><CMD>*<cs>\\r\\n`
Reply    `!<aa><CMD>,<field>,...*<cs>\\r\\n`

- aa: the instrument's address, two decimal digits 01..99;
- cs: two upper-case hex digits, the byte sum of everything between the leading
  `#` or `!` and the `*`, mod 256.

Commands
    ID   -> !aaID,<model>,<serial>,<resolution arcsec>,<range arcsec>
    RD   -> !aaRD,<n>,<ticks>,<phi_x>,<phi_y>,<phi_z>,<status>
            one reading, taken when the request arrives: n counts readings since
            power-up (decimal); ticks (8 hex digits) is the sample's time stamp on
            the station's 50 ns timebase (the interface's sync input, as on the
            counter/timer and the read heads; wraps every 214.7 s); phi about x, y, z in
            arc-seconds, signed, 3 decimals; status 0 ok, 1 over range (an axis
            beyond +-range), 2 sensor fault (no pendulum signal).
    other -> !aaER,BADCMD     a request with a bad checksum -> !aaER,CHECKSUM

Errors: no reply -> DeviceTimeout; malformed or truncated reply -> FrameError; bad
checksum -> ChecksumError; ER -> DeviceFault (field "reply"); status 1 -> DeviceFault
naming the axis, its reading and the range; status 2 -> DeviceFault (field "status");
an instrument whose ID disagrees with the station configuration -> DeviceFault on
open; port gone -> Disconnected. Both commands are queries and are retried (a
repeated RD is simply a newer reading with its own time stamp); faults are not.
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.errors import DeviceFault, DeviceTimeout, FrameError
from drivers.gradiometer.protocol import DEVICE, STATUS, decode_line, encode_line, parse_reading
from drivers.serial_port import SerialDevice, TickUnwrapper, with_retries
from station.clock import Clock

# ---------------------------------------------------------------- driver


@dataclass(frozen=True)
class Identity:
    model: str
    serial: str
    resolution_arcsec: float
    range_arcsec: float


@dataclass(frozen=True)
class TiltReading:
    n: int
    t_s: float  # station time of the sample
    phi_x_arcsec: float
    phi_y_arcsec: float
    phi_z_arcsec: float


class Gradiometer(SerialDevice):
    """Driver of the gradiometer: identity and time-stamped readings.

    `clock`: the station clock whose timebase the instrument's stamps share; each
    stamp is unwrapped against the clock when its reply arrives (valid while replies
    come within half a wrap, 107 s, of their sample).
    """

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 115_200,
        address: int = 1,
        timeout_s: float = 0.5,
        retries: int = 2,
        clock: Clock | None = None,
    ) -> None:
        if not 1 <= address <= 99:
            raise ValueError(f"gradiometer address {address!r}: allowed 1 .. 99")
        super().__init__(port, baud, clock=clock)
        self.address = address
        self.timeout_s = timeout_s
        self.retries = retries
        self._unwrap = TickUnwrapper(clock, absolute=clock is not None)

    # ---- transactions

    def _transact(self, command: str) -> list[str]:
        lines = self.lines
        with self._io:
            lines.clear()  # a partial line left by a failed attempt
            lines.link.write(encode_line("#", self.address, command))
            deadline_s = self._link_clock.now_s() + self.timeout_s
            while True:
                left_s = deadline_s - self._link_clock.now_s()
                if left_s <= 0:
                    raise DeviceTimeout(DEVICE, f"no reply to {command} within {self.timeout_s:g} s")
                try:
                    line = lines.read_line(left_s)
                except DeviceTimeout:
                    raise DeviceTimeout(DEVICE, f"no reply to {command} within {self.timeout_s:g} s") from None
                address, reply, fields = decode_line(line)
                if address != self.address:
                    continue  # another instrument on the line
                if reply == "ER":
                    raise DeviceFault(DEVICE, f"{command} rejected", field="reply", value=",".join(fields))
                if reply == command:  # a late reply to an earlier attempt is as good: a reading carries its stamp
                    return fields

    def _query(self, command: str) -> list[str]:
        return with_retries(lambda: self._transact(command), self.retries)

    def identify(self) -> Identity:
        f = self._query("ID")
        try:
            return Identity(f[0], f[1], float(f[2]), float(f[3]))
        except (IndexError, ValueError) as exc:
            raise FrameError(DEVICE, f"malformed identity {f!r}") from exc

    def read(self) -> TiltReading:
        """One reading, time-stamped by the instrument (query, retried)."""
        n, ticks, phi, status = parse_reading(self._query("RD"))
        if status == 1:
            axis, value = max(zip("xyz", phi, strict=True), key=lambda av: abs(av[1]))
            raise DeviceFault(DEVICE, "over range", field=f"phi_{axis}_arcsec", value=value,
                              allowed="within the instrument's range (ID)")  # fmt: skip
        if status != 0:
            raise DeviceFault(DEVICE, STATUS.get(status, "unknown status"), field="status", value=status,
                              allowed="0 (ok)")  # fmt: skip
        self._unwrap.reset()
        return TiltReading(n, self._unwrap.unwrap_s(ticks), *phi)
