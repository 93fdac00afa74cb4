"""Wire format of the indexing head (Zaber-style ASCII): the one codec that its driver and its emulator share.

Command and reply grammar as listed in drivers.indexing_head.driver:
`/<device> <axis> <id> <command> [<data>]:<lrc>\\n` and
`@<device:02d> <axis> <id> <flag> <status> <warning> <data>:<lrc>\\r\\n`.
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.errors import ChecksumError, FrameError

DEVICE = "indexing head"


# ---------------------------------------------------------------- line codec


def lrc(body: bytes) -> int:
    """Zaber ASCII checksum: two's complement of the byte sum, mod 256."""
    return (256 - sum(body) % 256) % 256


def encode_message(lead: str, body: str) -> bytes:
    """`<lead><body>:<lrc>` (no terminator)."""
    b = body.encode("ascii")
    return lead.encode("ascii") + b + b":%02X" % lrc(b)


@dataclass(frozen=True, slots=True)
class Reply:
    device: int
    axis: int
    msg_id: int | None
    ok: bool
    busy: bool
    warning: str  # "--" when none
    data: str


def decode_reply(line: bytes) -> Reply:
    """Parse a `@...` reply line (terminator stripped); typed errors when bad."""
    if not line.startswith(b"@"):
        raise FrameError(DEVICE, f"not a reply: {line!r}")
    body, sep, cs = line[1:].rpartition(b":")
    if not sep or len(cs) != 2:
        raise FrameError(DEVICE, f"reply without checksum (truncated?): {line!r}")
    try:
        got = int(cs, 16)
    except ValueError as exc:
        raise FrameError(DEVICE, f"malformed checksum in {line!r}") from exc
    if got != lrc(body):
        raise ChecksumError(DEVICE, f"reply {line!r}: checksum {got:02X} != computed {lrc(body):02X}")
    try:
        tokens = body.decode("ascii").split(" ")
        dev, axis, *rest = tokens
        msg_id: int | None = None
        if rest and rest[0].isdigit():
            msg_id = int(rest[0])
            rest = rest[1:]
        if len(rest) < 4:
            raise ValueError("too few fields")
        flag, status, warn = rest[:3]
        data = " ".join(rest[3:])
        if flag not in ("OK", "RJ") or status not in ("BUSY", "IDLE"):
            raise ValueError(f"flag {flag!r} / status {status!r}")
        return Reply(int(dev), int(axis), msg_id, flag == "OK", status == "BUSY", warn, data)
    except (UnicodeDecodeError, ValueError) as exc:
        raise FrameError(DEVICE, f"malformed reply {line!r}: {exc}") from exc


WARNING_ORDER = ("FS", "NI", "WR")  # most important first


def encode_command(device: int, axis: int, msg_id: int, command: str) -> bytes:
    """A command line, terminator included: `/<device> <axis> <id> <command>:<lrc>\\n`."""
    return encode_message("/", f"{device} {axis} {msg_id} {command}".rstrip()) + b"\n"


def encode_reply(device: int, axis: int, msg_id: int | None, ok: bool, busy: bool, warning: str, data: str) -> bytes:
    """A reply line without its CR LF terminator (the emulator may damage it first)."""
    fields = [f"{device:02d}", str(axis)]
    if msg_id is not None:
        fields.append(f"{msg_id:02d}")
    fields += ["OK" if ok else "RJ", "BUSY" if busy else "IDLE", warning, data]
    return encode_message("@", " ".join(fields))


@dataclass(frozen=True, slots=True)
class Command:
    device: int  # 0: all devices
    axis: int  # 0: all axes
    msg_id: int | None
    words: list[str]  # the command and its data; [] for a status request


def decode_command(line: bytes) -> Command | None:
    """A `/...` command line (terminator stripped); None for what a controller silently drops:
    not a command, a bad checksum, no device and axis numbers."""
    if not line.startswith(b"/"):
        return None
    body, sep, cs = line[1:].partition(b":")
    if sep and (len(cs) != 2 or int(cs, 16) != lrc(body)):
        return None  # Zaber devices silently drop commands with a bad checksum
    tokens = body.decode("ascii", "replace").split()
    if len(tokens) < 2 or not tokens[0].isdigit() or not tokens[1].isdigit():
        return None
    rest = tokens[2:]
    mid = None
    if rest and rest[0].isdigit():
        mid = int(rest[0])
        rest = rest[1:]
    return Command(int(tokens[0]), int(tokens[1]), mid, rest)
