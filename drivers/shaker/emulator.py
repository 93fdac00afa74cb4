"""Emulator of the shaker's vibration controller (protocol in drivers.shaker.protocol).

The table's motion belongs to the world: START sets the world's shared `ShakerMotion`
(`world.shared("shaker", ShakerMotion)`, what the IMU's emulator reads) running from now on,
STOP ramps it down, ABORT and alarms stop it within ALARM_STOP_S; STAT? reports the state
and the control accelerometer's level from it, all at world.clock time. The controller
refuses what lies outside its table's envelope (the same [shaker] section the driver checks,
ER RANGE). Random tests are random-phase multisines drawn from the world's seed.
Replies are a few dozen bytes per command: the line pacing of PtyEmulator is all the rate
limit needed.

Faults: NO_ANSWER (ignore the next `count` commands), GARBLE / TRUNCATE / CRC_ERROR (the next
reply), DISCONNECT; device-specific `alarm(name)`: the drive trips (e.g. OVERTRAVEL, AMP_TEMP).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.errors import LimitError
from drivers.pty_link import Fault, PtyEmulator, garble, truncate
from drivers.serial_port import crc16
from drivers.shaker import envelope as sh
from drivers.shaker.protocol import decode_command, encode_reply
from station.twin.shaker_motion import Drive, ShakerMotion, random_drive, sine_drive

ALARM_STOP_S = 0.02  # an amplifier trip stops the table within tens of milliseconds
IDN = "THV710A-EMU 0002"


class ShakerEmulator(PtyEmulator):
    name = "shaker-emulator"
    supported_faults = frozenset({Fault.NO_ANSWER, Fault.GARBLE, Fault.TRUNCATE, Fault.CRC_ERROR, Fault.DISCONNECT})

    def __init__(self, world: Any, limits: sh.ShakerSection, **kw: Any) -> None:
        super().__init__(world.clock, baud=limits.baud, **kw)
        self.limits = limits
        self.motion: ShakerMotion = world.shared("shaker", ShakerMotion)
        self.rng = np.random.default_rng(int(world.rng.integers(2**63)))
        self.test: Drive | None = None
        self.latched: str | None = None
        self.commands: list[str] = []  # log of received command texts, for tests

    def alarm(self, name: str) -> None:
        """Trip the drive (device-specific fault): the table stops, then the alarm latches (whoever reads the alarm
        finds the table stopping, even in the middle of a ramp-down)."""
        self.motion.stop(self.clock.now_s(), ALARM_STOP_S)
        self.latched = name

    def on_bytes(self, data: bytes) -> None:
        for line in self.command_lines(data):
            self._handle(line)

    def _reply(self, ok: bool, data: str) -> None:
        line = encode_reply(ok, data)
        if self.faults.take(Fault.GARBLE):
            line = garble(line)
        elif self.faults.take(Fault.TRUNCATE):
            line = truncate(line)
        elif self.faults.take(Fault.CRC_ERROR):
            line = line[:-4] + b"%04X" % (crc16(line[:-5]) ^ 0x0101)
        self.send(line + b"\r\n")

    def _handle(self, line: bytes) -> None:
        words = decode_command(line)
        if words is None:
            self._reply(False, "SYNTAX checksum")
            return
        self.commands.append(" ".join(words))
        ok, data = self._execute(words)
        self._reply(ok, data)

    def _state(self, now: float) -> str:
        return "ALARM" if self.latched is not None else self.motion.phase(now).upper()

    def _execute(self, words: list[str]) -> tuple[bool, str]:
        now = self.clock.now_s()
        try:
            match words:
                case ["IDN?"]:
                    return True, IDN
                case ["STAT?"]:
                    mode = "NONE" if self.test is None else self.test.mode.upper()
                    level = self.motion.level_g(now)
                    return True, f"{self._state(now)} {mode} {level:.5f} {self.latched or '--'}"
                case ["SINE" | "RAND", *_] if self.motion.moving(now):
                    return False, "BUSY the table runs"
                case ["SINE", f, a]:
                    sh.check_sine(self.limits, float(f), float(a))
                    self.test = sine_drive(float(f), float(a), sh.G_STANDARD_MPS2)
                    return True, "0"
                case ["RAND", rms, lo, hi]:
                    sh.check_random(self.limits, float(rms), float(lo), float(hi))
                    self.test = random_drive(float(rms), float(lo), float(hi), sh.G_STANDARD_MPS2, self.rng)
                    return True, "0"
                case ["START", ramp]:
                    sh.check_ramp(self.limits, float(ramp))
                    if self.latched is not None:
                        return False, f"ALARM {self.latched} latched"
                    if self.test is None:
                        return False, "SYNTAX no test set"
                    if self.motion.moving(now):
                        return False, "BUSY the table runs"
                    self.motion.start(self.test, now, float(ramp))
                    return True, "0"
                case ["STOP", ramp]:
                    sh.check_ramp(self.limits, float(ramp))
                    self.motion.stop(now, float(ramp))
                    return True, "0"
                case ["ABORT"]:
                    self.motion.stop(now, ALARM_STOP_S)
                    return True, "0"
                case ["ALARM:CLR"]:
                    self.latched = None
                    return True, "0"
                case _:
                    return False, f"SYNTAX {' '.join(words)!r}"
        except LimitError as exc:
            return False, f"RANGE {exc.field} = {exc.value}: allowed {exc.allowed}"
        except ValueError:
            return False, f"SYNTAX bad number in {' '.join(words)!r}"
