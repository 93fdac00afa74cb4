"""Wire format of the PIGA electronics (SCPI-like ASCII lines with an XOR checksum): the one codec that its
driver and its emulator share.

`<body>*<cs>\\n` commands, `<body>*<cs>\\r\\n` replies, the commands and replies as listed in
drivers.piga_electronics.driver.
"""

from __future__ import annotations

import functools

from drivers.errors import ChecksumError, FrameError

DEVICE = "PIGA electronics"
SERVO_STATES = ("LOCK", "SETTLE", "FAULT")
OFFSET_DECIMALS = 3


def checksum(body: bytes) -> int:
    """XOR of the body's bytes (NMEA style)."""
    return functools.reduce(lambda a, b: a ^ b, body, 0)


def encode_line(body: str) -> bytes:
    """`<body>*<cs>` (no terminator)."""
    b = body.encode("ascii")
    return b + b"*%02X" % checksum(b)


def decode_line(line: bytes) -> str:
    """The body of a `<body>*<cs>` line (terminator stripped); FrameError or ChecksumError when bad."""
    body, sep, cs = line.rpartition(b"*")
    if not sep or len(cs) != 2:
        raise FrameError(DEVICE, f"reply without checksum (truncated?): {line!r}")
    try:
        got = int(cs, 16)
        text = body.decode("ascii")
    except (ValueError, UnicodeDecodeError) as exc:
        raise FrameError(DEVICE, f"malformed reply {line!r}") from exc
    if got != checksum(body):
        raise ChecksumError(DEVICE, f"reply {line!r}: checksum {got:02X} != computed {checksum(body):02X}")
    return text


def decode_command(line: bytes) -> str | None:
    """The command of a `<body>*<cs>` line (terminator stripped, blanks trimmed); None if its checksum is
    missing or wrong (the board answers that with error -310)."""
    body, sep, cs = line.rpartition(b"*")
    if not sep or len(cs) != 2 or cs.upper() != b"%02X" % checksum(body):
        return None
    return body.decode("ascii", "replace").strip()
