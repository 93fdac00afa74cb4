"""Emulator of the reference-mark monitor (protocol in drivers.reference_marks.driver and .protocol).

Each poll reports the crossings world.reference_crossings_s gives for the
station time elapsed since the previous poll, and a heartbeat every second of
station time. Output is small (at most 10 crossings per station second), so a
fast virtual clock only needs the FIFO guard of PtyEmulator: a crossing
that does not fit is dropped and its number skipped, which the driver counts.
Crossings hidden by an alarm are not seen, hence not numbered.

Faults: NO_ANSWER (commands ignored, `count` of them, and the device silent
while armed), GARBLE / TRUNCATE / CRC_ERROR (the next line), SIGNAL_LOSS and
OVERSPEED (alarm raised while armed, until cleared; no crossings meanwhile),
DISCONNECT.
"""

from __future__ import annotations

from typing import Any

from drivers.pty_link import LINK_FAULTS, Fault, PtyEmulator, garble, truncate
from drivers.reference_marks.protocol import HEARTBEAT_S, decode_line, encode_line
from drivers.serial_port import ticks_of


class ReferenceEmulator(PtyEmulator):
    name = "reference-emulator"
    supported_faults = LINK_FAULTS | {Fault.SIGNAL_LOSS, Fault.OVERSPEED}

    def __init__(self, world: Any, *, baud: int = 115_200, **kw: Any) -> None:
        super().__init__(world.clock, baud=baud, **kw)
        self.world = world
        self.reporting = False
        self.count = 0
        self.alarm = 0
        self._last_s = 0.0
        self._last_heartbeat_s = 0.0

    def _emit(self, *fields: object) -> None:
        line = encode_line(*fields)
        if self.faults.take(Fault.GARBLE):
            line = garble(line[:-2]) + b"\r\n"
        elif self.faults.take(Fault.TRUNCATE):
            line = truncate(line[:-2]) + b"\r\n"
        elif self.faults.take(Fault.CRC_ERROR):
            line = line[:-4] + b"%02X\r\n" % (int(line[-4:-2], 16) ^ 0x5A)
        if len(line) <= self.tx_room():
            self.send(line)

    # ---- commands

    def on_bytes(self, data: bytes) -> None:
        for line in self.command_lines(data):
            self._command(line)

    def _command(self, line: bytes) -> None:
        try:
            fields = decode_line(line)
        except Exception:
            self._emit("ERR", "CHECKSUM")
            return
        now = self.clock.now_s()
        cmd = fields[0]
        if cmd == "START":
            self.reporting = True
            self.count = 0
            self._last_s = now
            self._last_heartbeat_s = now
            self._emit("OK", cmd)
        elif cmd == "STOP":
            self.reporting = False
            self._emit("OK", cmd)
        elif cmd == "STATUS?":
            self._emit("ST", int(self.reporting), self.alarm, self.count, f"{ticks_of(now):08X}")
        else:
            self._emit("ERR", "BADCMD")

    # ---- events

    def on_poll(self, now_s: float) -> None:
        if not self.reporting or now_s <= self._last_s:
            return
        if self.faults.active(Fault.NO_ANSWER):
            self._last_s = self._last_heartbeat_s = now_s
            return
        alarm = 1 if self.faults.active(Fault.SIGNAL_LOSS) else 2 if self.faults.active(Fault.OVERSPEED) else 0
        if alarm != self.alarm:
            self.alarm = alarm
            self._emit("A", alarm, f"{ticks_of(now_s):08X}")
        crossings = self.world.reference_crossings_s(self._last_s, now_s)
        self._last_s = now_s
        if not self.alarm:  # a read head without signal sees no reference mark
            for t in crossings:
                if len(self._tx) + 32 <= self.fifo_bytes:
                    self._emit("Z", self.count, f"{ticks_of(float(t)):08X}")
                self.count += 1
        if now_s - self._last_heartbeat_s >= HEARTBEAT_S:
            self._last_heartbeat_s = now_s
            self._emit("H", f"{ticks_of(now_s):08X}")
