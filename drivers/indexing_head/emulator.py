"""Emulator of the indexing head's controller (protocol in drivers.indexing_head.driver and .protocol).

Motion belongs to the world: `move abs` calls world.index_command_move,
`stop` world.index_stop, `get pos` reads world.index_position_deg (the
head's own encoder) and BUSY is world.index_busy, all at world.clock time.
Replies are a few dozen bytes per command, so the only rate limit needed is
the line pacing of PtyEmulator.

Faults: NO_ANSWER (ignore the next `count` commands), GARBLE / TRUNCATE /
CRC_ERROR (the next reply), DISCONNECT.
"""

from __future__ import annotations

import math
from typing import Any

from drivers.indexing_head.protocol import WARNING_ORDER, decode_command, encode_reply
from drivers.pty_link import Fault, PtyEmulator, garble, truncate


class IndexingEmulator(PtyEmulator):
    name = "indexing-emulator"
    supported_faults = frozenset({Fault.NO_ANSWER, Fault.GARBLE, Fault.TRUNCATE, Fault.CRC_ERROR, Fault.DISCONNECT})

    def __init__(
        self,
        world: Any,
        *,
        baud: int = 115_200,
        device: int = 1,
        counts_per_deg: float = 10_000.0,
        limit_deg: float = 720.0,
        homed: bool = False,
        **kw: Any,
    ) -> None:
        super().__init__(world.clock, baud=baud, **kw)
        self.world = world
        self.device = device
        self.counts_per_deg = counts_per_deg
        self.limit_counts = round(limit_deg * counts_per_deg)
        self.warnings: set[str] = set() if homed else {"WR"}
        self.commands: list[str] = []  # log of received command texts, for tests

    def on_bytes(self, data: bytes) -> None:
        for line in self.command_lines(data):
            self._handle(line)

    def next_due_s(self, now_s: float) -> float:
        """Never: the controller only answers commands (motion is the world's, read when asked)."""
        return math.inf

    def _reply(self, axis: int, mid: int | None, ok: bool, data: str) -> None:
        now = self.clock.now_s()
        busy = self.world.index_busy(now)
        warn = next((w for w in WARNING_ORDER if w in self.warnings), "--")
        line = encode_reply(self.device, axis, mid, ok, busy, warn, data)
        if self.faults.take(Fault.GARBLE):
            line = garble(line)
        elif self.faults.take(Fault.TRUNCATE):
            line = truncate(line)
        elif self.faults.take(Fault.CRC_ERROR):
            line = line[:-2] + b"%02X" % ((int(line[-2:], 16) + 1) % 256)
        self.send(line + b"\r\n")

    def _handle(self, line: bytes) -> None:
        command = decode_command(line)
        if command is None or command.device not in (0, self.device):
            return
        axis, mid, rest = command.axis, command.msg_id, command.words
        self.commands.append(" ".join(rest))
        if axis not in (0, 1):
            self._reply(axis, mid, False, "BADAXIS")
            return
        ok, data = self._execute(rest)
        self._reply(axis, mid, ok, data)

    def _execute(self, words: list[str]) -> tuple[bool, str]:
        now = self.clock.now_s()
        w = self.world
        match words:
            case []:
                return True, "0"
            case ["home"]:
                w.index_command_move(0.0, now)
                self.warnings.discard("WR")
                return True, "0"
            case ["move", "abs", value]:
                try:
                    counts = int(value)
                except ValueError:
                    return False, "BADDATA"
                if abs(counts) > self.limit_counts:
                    return False, "BADDATA"
                w.index_command_move(counts / self.counts_per_deg, now)
                return True, "0"
            case ["stop"]:
                if w.index_busy(now):
                    self.warnings.add("NI")
                w.index_stop(now)
                return True, "0"
            case ["get", "pos"]:
                return True, str(round(w.index_position_deg(now) * self.counts_per_deg))
            case ["warnings"]:
                return True, self._warning_list()
            case ["warnings", "clear"]:
                listed = self._warning_list()
                self.warnings &= {"WR"}  # WR clears only by homing
                return True, listed
            case _:
                return False, "BADCOMMAND"

    def _warning_list(self) -> str:
        flags = [f for f in WARNING_ORDER if f in self.warnings]
        return " ".join([f"{len(flags):02d}", *flags])
