"""Wire format of the electronic gradiometer (addressed ASCII lines with a byte-sum checksum): the one codec
that its driver and its emulator share.

Requests `#<aa><CMD>*<cs>\\r\\n`, replies `!<aa><CMD>,<field>,...*<cs>\\r\\n`, the commands and
their fields as listed in drivers.gradiometer.driver.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drivers.errors import ChecksumError, FrameError

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


def format_reading(n: int, ticks: int, phi_arcsec: Sequence[float] | np.ndarray, status: int) -> tuple[str, ...]:
    """The fields of an RD reply: n, ticks (8 hex digits), phi_x, phi_y, phi_z (arcsec, 3 decimals), status."""
    return (str(n), f"{ticks:08X}", *(f"{v:+.3f}" for v in phi_arcsec), str(status))


def parse_reading(fields: list[str]) -> tuple[int, int, tuple[float, ...], int]:
    """(n, ticks, (phi_x, phi_y, phi_z) in arcsec, status) of an RD reply's fields; FrameError if malformed."""
    try:
        n, ticks, status = int(fields[0]), int(fields[1], 16), int(fields[5])
        phi = tuple(float(v) for v in fields[2:5])
    except (IndexError, ValueError) as exc:
        raise FrameError(DEVICE, f"malformed reading {fields!r}") from exc
    return n, ticks, phi, status
