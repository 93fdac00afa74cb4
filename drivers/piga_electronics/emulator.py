"""Emulator of the PIGA's electronics (protocol in drivers.piga_electronics.protocol), with the float it servoes.

The emulator owns the simulated instrument's float (station.twin.nonlinear_error.FloatModel, seed 004's by
default): whenever the digital offset changes, or the simulated operator has the laser fine-weight adjusting
machine remove mass from the float (operator action `float_mass_removal` = {"mass_mg", "radius_mm",
"angle_deg"}), it puts the float's kzz at that offset into the world's twin (`world.set_twin`), so every
later counter window sees it. After an offset change the servo reports SETTLE for `settle_s` of station
time (beta error decaying from the step), then LOCK.

Faults: NO_ANSWER (ignore the next `count` commands), GARBLE / TRUNCATE / CRC_ERROR (the next reply),
DISCONNECT; and `lose_lock()`, the device's own fault: the servo latches FAULT until *CLS.
"""

from __future__ import annotations

import math
import re
import threading
from dataclasses import replace
from typing import Any

from drivers.errors import DriverError
from drivers.piga_electronics.protocol import OFFSET_DECIMALS, decode_command, encode_line
from drivers.pty_link import Fault, PtyEmulator, garble, truncate
from station.twin.nonlinear_error import ARCSEC_RAD, MASS_REMOVAL, FloatModel

IDENTITY = "BIACD,PIGA-PCB,SIM-0001,2.1"
NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)")


class PigaElectronicsEmulator(PtyEmulator):
    name = "piga-electronics-emulator"
    supported_faults = frozenset({Fault.NO_ANSWER, Fault.GARBLE, Fault.TRUNCATE, Fault.CRC_ERROR, Fault.DISCONNECT})

    def __init__(
        self,
        world: Any,
        *,
        baud: int = 115_200,
        float_model: FloatModel | None = None,
        offset_range_arcsec: float = 30.0,
        settle_s: float = 2.0,
        poll_wall_s: float = 0.05,  # nothing streams: the worker wakes on each command, the polls only check faults
        **kw: Any,
    ) -> None:
        super().__init__(world.clock, baud=baud, poll_wall_s=poll_wall_s, **kw)
        self.world = world
        self.float_model = float_model or FloatModel.seed004(world.twin.instrument.kz)
        self.offset_range_arcsec = offset_range_arcsec
        self.settle_s = settle_s
        self.offset_arcsec = 0.0
        self.commands: list[str] = []  # received command bodies, for tests
        self._errors: list[str] = []
        self._faulted = False
        self._step_arcsec = 0.0
        self._changed_s = -math.inf
        self._lock = threading.Lock()
        world.on_operator(MASS_REMOVAL, self._remove_mass)
        self._apply()

    # ---- physics

    def _apply(self) -> None:
        """Put the float's kzz at the offset in force into the world's twin."""
        twin = self.world.twin
        kzz = float(self.float_model.kzz_radps_per_g2(self.offset_arcsec * ARCSEC_RAD, twin.instrument.kz))
        self.world.set_twin(replace(twin, instrument=replace(twin.instrument, kzz=kzz)))

    def _remove_mass(self, value: Any, t_s: float) -> None:
        """The simulated operator's mass removal on the float (seed 004 section 5.2, Fig. 8)."""
        keys = ("mass_mg", "radius_mm", "angle_deg")
        if not isinstance(value, dict) or sorted(value) != sorted(keys):
            raise DriverError(
                "simulated operator", f"{MASS_REMOVAL} needs {{{', '.join(keys)}}}", field=MASS_REMOVAL, value=value
            )
        mass_mg, radius_mm, angle_deg = (value[k] for k in keys)
        if not (0 <= mass_mg <= 1000 and 0 < radius_mm <= 100 and 0 < angle_deg < 90):
            raise DriverError(
                "simulated operator",
                "mass removal outside what the machine can do",
                field=MASS_REMOVAL,
                value=value,
                allowed="mass_mg 0 .. 1000, radius_mm 0 .. 100, angle_deg 0 .. 90 (exclusive)",
            )
        with self._lock:
            self.float_model = self.float_model.after_mass_removal(
                mass_mg * 1e-6, radius_mm * 1e-3, math.radians(angle_deg)
            )
            self._apply()

    def lose_lock(self) -> None:
        """The servo loses lock (torque motor saturated): FAULT is latched until *CLS."""
        with self._lock:
            self._faulted = True

    # ---- protocol

    def on_bytes(self, data: bytes) -> None:
        for line in self.command_lines(data):
            self._reply(self._handle(line))

    def _reply(self, body: str) -> None:
        line = encode_line(body)
        if self.faults.take(Fault.GARBLE):
            line = garble(line)
        elif self.faults.take(Fault.TRUNCATE):
            self.send(truncate(line))
            return
        elif self.faults.take(Fault.CRC_ERROR):
            line = line[:-2] + b"%02X" % (int(line[-2:], 16) ^ 0x01)
        self.send(line + b"\r\n")

    def _error(self, code: int, text: str) -> str:
        self._errors.append(f'{code},"{text}"')
        return f'ERR {code},"{text}"'

    def _handle(self, line: bytes) -> str:
        command = decode_command(line)
        if command is None:
            return self._error(-310, "checksum")
        self.commands.append(command)
        with self._lock:
            return self._execute(command.split(maxsplit=1), self.clock.now_s())

    def _execute(self, words: list[str], now_s: float) -> str:
        match words:
            case ["*IDN?"]:
                return IDENTITY
            case ["*CLS"]:
                self._errors.clear()
                if self._faulted:
                    self._faulted = False
                    self._changed_s = now_s
                return "OK"
            case ["SYST:ERR?"]:
                return self._errors.pop(0) if self._errors else '0,"No error"'
            case ["SERV:OFFS?"]:
                return f"{self.offset_arcsec:.{OFFSET_DECIMALS}f}"
            case ["SERV:STAT?"]:
                return self._status(now_s)
            case ["SERV:OFFS", value]:
                return self._set_offset(value, now_s)
            case _:
                return self._error(-100, "unknown command")

    def _set_offset(self, value: str, now_s: float) -> str:
        if not NUMBER.fullmatch(value):
            return self._error(-104, "data type")
        offset = round(float(value), OFFSET_DECIMALS)
        if abs(offset) > self.offset_range_arcsec:
            return self._error(-222, "data out of range")
        if self._faulted:
            return self._error(301, "servo fault")
        self._step_arcsec = self.offset_arcsec - offset
        self._changed_s = now_s
        self.offset_arcsec = offset
        self._apply()
        return "OK"

    def _status(self, now_s: float) -> str:
        if self._faulted:
            return "FAULT,99.999"
        since = now_s - self._changed_s
        if since < self.settle_s:
            return f"SETTLE,{self._step_arcsec * math.exp(-5.0 * since / self.settle_s):.3f}"
        return "LOCK,0.000"
