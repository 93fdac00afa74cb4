"""Wire format of the shaker's vibration controller (ASCII lines with a CRC-16): the one codec that its driver
and its emulator share.

Commands `<text>*<crc>\\n`, replies `<OK|ER> <data>*<crc>\\r\\n`, crc the CRC-16/CCITT-FALSE of the text
before `*` as four upper-case hex digits; the commands and replies as listed in drivers.shaker.driver.
"""

from __future__ import annotations

from drivers.errors import ChecksumError, FrameError
from drivers.serial_port import crc16

DEVICE = "shaker controller"
STATES = ("IDLE", "RAMP_UP", "RUN", "RAMP_DOWN", "ALARM")
MODES = ("NONE", "SINE", "RANDOM")

# ---------------------------------------------------------------- line codec


def encode_line(text: str) -> bytes:
    """`text*CRC` without the terminator."""
    body = text.encode("ascii")
    return body + b"*%04X" % crc16(body)


def decode_line(line: bytes) -> bytes:
    """The text of a `text*CRC` line (terminator stripped); FrameError / ChecksumError when bad."""
    body, sep, crc = line.rpartition(b"*")
    if not sep or len(crc) != 4:
        raise FrameError(DEVICE, f"line without checksum (truncated?): {line!r}")
    try:
        got = int(crc, 16)
    except ValueError as exc:
        raise FrameError(DEVICE, f"malformed checksum in {line!r}") from exc
    if got != crc16(body):
        raise ChecksumError(DEVICE, f"reply {line!r}: crc {got:04X} != computed {crc16(body):04X}")
    return body


def encode_reply(ok: bool, data: str) -> bytes:
    """`OK <data>*CRC` or `ER <data>*CRC` without the terminator."""
    return encode_line(f"{'OK' if ok else 'ER'} {data}")


def decode_command(line: bytes) -> list[str] | None:
    """The words of a command line (terminator stripped); None if its crc is missing or wrong (ER SYNTAX)."""
    body, sep, crc = line.rpartition(b"*")
    if not sep or len(crc) != 4 or crc.upper() != b"%04X" % crc16(body):
        return None
    return body.decode("ascii", "replace").split()
