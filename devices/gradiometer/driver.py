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

import time
from dataclasses import dataclass
from typing import Any

from devices.config import SerialSection, in_range, spec
from devices.errors import ChecksumError, DeviceFault, DeviceTimeout, FrameError
from devices.registry import DeviceKind
from devices.serial_port import SerialDevice, TickUnwrapper, with_retries
from station.clock import Clock

DEVICE = "gradiometer"
STATUS = {0: "ok", 1: "over range", 2: "sensor fault (no pendulum signal)"}


# ---------------------------------------------------------------- line codec


def checksum(body: bytes) -> int:
    return sum(body) % 256


def encode_line(lead: str, address: int, command: str, *fields: object) -> bytes:
    """`<lead><aa><CMD>[,f1,...]*<cs>\\r\\n`."""
    body = (f"{address:02d}{command}" + "".join(f",{f}" for f in fields)).encode("ascii")
    return lead.encode("ascii") + body + b"*%02X\r\n" % checksum(body)


def decode_line(line: bytes, lead: bytes = b"!") -> tuple[int, str, list[str]]:
    """(address, command, fields) of a line without its terminator; typed errors when bad."""
    if not line.startswith(lead) or len(line) < 8 or line[-3:-2] != b"*":
        raise FrameError(DEVICE, f"malformed or truncated line {line!r}")
    body = line[1:-3]
    try:
        got = int(line[-2:], 16)
    except ValueError as exc:
        raise FrameError(DEVICE, f"malformed checksum in {line!r}") from exc
    if got != checksum(body):
        raise ChecksumError(DEVICE, f"line {line!r}: checksum {got:02X} != computed {checksum(body):02X}")
    try:
        text = body.decode("ascii")
        head, *fields = text.split(",")
        return int(head[:2]), head[2:], fields
    except (UnicodeDecodeError, ValueError) as exc:
        raise FrameError(DEVICE, f"malformed line {line!r}") from exc


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
        super().__init__(port, baud)
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
            deadline = time.monotonic() + self.timeout_s
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DeviceTimeout(DEVICE, f"no reply to {command} within {self.timeout_s:g} s")
                try:
                    line = lines.read_line(left)
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
        f = self._query("RD")
        try:
            n, ticks, status = int(f[0]), int(f[1], 16), int(f[5])
            phi = tuple(float(v) for v in f[2:5])
        except (IndexError, ValueError) as exc:
            raise FrameError(DEVICE, f"malformed reading {f!r}") from exc
        if status == 1:
            axis, value = max(zip("xyz", phi, strict=True), key=lambda av: abs(av[1]))
            raise DeviceFault(DEVICE, "over range", field=f"phi_{axis}_arcsec", value=value,
                              allowed="within the instrument's range (ID)")  # fmt: skip
        if status != 0:
            raise DeviceFault(DEVICE, STATUS.get(status, "unknown status"), field="status", value=status,
                              allowed="0 (ok)")  # fmt: skip
        self._unwrap.reset()
        return TiltReading(n, self._unwrap.unwrap_s(ticks), *phi)


# ---------------------------------------------------------------- station plug-in


@dataclass(frozen=True)
class GradiometerSection(SerialSection):
    """`[gradiometer]` of a station file."""

    address: int = spec(in_range(1, 99))
    resolution_arcsec: float = spec(in_range(0.0, 10.0, lo_open=True))
    range_arcsec: float = spec(in_range(0.0, 36_000.0, lo_open=True))


def open_gradiometer(section: GradiometerSection, clock: Clock) -> Gradiometer:
    """Open the port and check that the instrument answering is the one configured."""
    grad = Gradiometer(section.port or "", baud=section.baud, address=section.address, clock=clock).open()
    try:
        ident = grad.identify()
        for name in ("resolution_arcsec", "range_arcsec"):
            got, want = getattr(ident, name), getattr(section, name)
            if abs(got - want) > 1e-9 * max(abs(want), 1.0):
                raise DeviceFault(DEVICE, f"instrument {ident.model} {ident.serial} disagrees with [gradiometer]",
                                  field=name, value=got, allowed=f"{want:g} as configured")  # fmt: skip
    except BaseException:
        grad.close()
        raise
    return grad


def emulate_gradiometer(section: GradiometerSection, world: Any) -> Any:
    """The emulator on the simulated world (a GradiometerEmulator, started), configured as the section says."""
    from devices.gradiometer.emulator import GradiometerEmulator

    emu = GradiometerEmulator(
        world, baud=section.baud, address=section.address,
        resolution_arcsec=section.resolution_arcsec, range_arcsec=section.range_arcsec,
    )  # fmt: skip
    emu.start()
    return emu


DEVICE_KIND = DeviceKind("gradiometer", GradiometerSection, open_gradiometer, emulate_gradiometer)
