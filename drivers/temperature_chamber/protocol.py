"""Wire format of the temperature chamber's controller (EI-Bisynch ASCII): the one codec that its driver and
its emulator share.

Read, reply and write messages, the BCC and the parameter mnemonics as listed in
drivers.temperature_chamber.driver.
"""

from __future__ import annotations

from functools import reduce
from operator import xor

from drivers.errors import ChecksumError, FrameError

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


def take_message(buf: bytearray) -> tuple[bytes, str, str | None, bool] | None:
    """(address field, mnemonic, data or None for a read, BCC good) of the host message at the start of
    `buf` (which starts with EOT), removed from it; None while it is incomplete."""
    if len(buf) < 8:
        return None
    address, rest = bytes(buf[1:5]), bytes(buf[5:])
    if rest[:1] == STX:
        end = rest.find(ETX)
        if end < 0 or len(rest) < end + 2:
            return None
        del buf[: 5 + end + 2]
        text = rest[1:end].decode("ascii", "replace")
        return address, text[:2], text[2:], rest[end + 1] == bcc(rest[1 : end + 1])
    end = rest.find(ENQ)
    if end < 0:
        if EOT in rest:  # a new message began: this one was cut short
            del buf[:1]
            return take_message(buf)
        return None
    del buf[: 5 + end + 1]
    return address, rest[:end].decode("ascii", "replace"), None, True
