"""Wire format of the reference mark monitor (NMEA-style ASCII lines): the one codec that its driver and
its emulator share.

`$` body `*` checksum CR LF, the checksum the XOR of the body's bytes as two upper-case hex digits;
the lines and their fields as listed in drivers.reference_marks.driver.
"""

from __future__ import annotations

from drivers.errors import ChecksumError, FrameError

DEVICE = "reference mark monitor"
HEARTBEAT_S = 1.0
ALARMS = {0: "clear", 1: "signal loss", 2: "overspeed"}
EVENTS = ("Z", "H", "A")


# ---------------------------------------------------------------- line codec


def nmea_checksum(body: bytes) -> int:
    c = 0
    for b in body:
        c ^= b
    return c


def encode_line(*fields: object) -> bytes:
    """b'$F1,F2,...*hh\\r\\n'."""
    body = ",".join(str(f) for f in fields).encode("ascii")
    return b"$%s*%02X\r\n" % (body, nmea_checksum(body))


def decode_line(line: bytes, device: str = DEVICE) -> list[str]:
    """Fields of a `$...*hh` line (terminator already stripped); typed errors if bad."""
    if not line.startswith(b"$") or len(line) < 4 or line[-3:-2] != b"*":
        raise FrameError(device, f"malformed line {line!r}")
    body = line[1:-3]
    try:
        got = int(line[-2:], 16)
    except ValueError as exc:
        raise FrameError(device, f"malformed checksum in {line!r}") from exc
    want = nmea_checksum(body)
    if got != want:
        raise ChecksumError(device, f"line {line!r}: checksum {got:02X} != computed {want:02X}")
    try:
        return body.decode("ascii").split(",")
    except UnicodeDecodeError as exc:
        raise FrameError(device, f"non-ASCII line {line!r}") from exc
