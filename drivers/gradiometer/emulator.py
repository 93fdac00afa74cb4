"""Emulator of the electronic gradiometer (protocol in drivers.gradiometer.driver and .protocol).

A reading is taken when its request arrives, at t = world.clock.now_s(): the table
top's tilt at the crank phase world.crank.phase_rad(t) (station.twin.table_tilt: about
x the twin's parasitic_rotation, about y and z the optional harmonics given here), plus
the instrument's Gaussian noise, rounded to its resolution and time-stamped on the
station's timebase. Replies are a few dozen bytes per request, so the line pacing of
PtyEmulator is the only rate limit needed.

Faults: NO_ANSWER (ignore the next `count` requests), GARBLE / TRUNCATE / CRC_ERROR
(the next reply), SIGNAL_LOSS (status 2 on readings while armed), DISCONNECT; an
over-range reading (status 1) comes from the physics, when a tilt exceeds `range_arcsec`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.errors import ChecksumError, FrameError
from drivers.gradiometer.protocol import decode_line, encode_line, format_reading
from drivers.pty_link import Fault, PtyEmulator, garble, truncate
from drivers.serial_port import ticks_of
from station.twin.table_tilt import ARCSEC_RAD, NO_TILT, TiltHarmonics, table_tilt_rad

MODEL = "EG-3"  # a three-axis electronic gradiometer


class GradiometerEmulator(PtyEmulator):
    name = "gradiometer-emulator"
    supported_faults = frozenset(
        {Fault.NO_ANSWER, Fault.GARBLE, Fault.TRUNCATE, Fault.CRC_ERROR, Fault.DISCONNECT, Fault.SIGNAL_LOSS}
    )

    def __init__(
        self,
        world: Any,
        *,
        baud: int = 115_200,
        address: int = 1,
        resolution_arcsec: float = 0.005,
        range_arcsec: float = 600.0,
        noise_arcsec: float = 0.005,
        about_y: TiltHarmonics = NO_TILT,
        about_z: TiltHarmonics = NO_TILT,
        serial: str = "0001",
        **kw: Any,
    ) -> None:
        super().__init__(world.clock, baud=baud, **kw)
        self.world = world
        self.address = address
        self.resolution_arcsec = resolution_arcsec
        self.range_arcsec = range_arcsec
        self.noise_arcsec = noise_arcsec
        self.about_y = about_y
        self.about_z = about_z
        self.serial = serial
        self.readings = 0
        self._rng = np.random.default_rng(int(world.rng.integers(2**63)))

    def on_bytes(self, data: bytes) -> None:
        for line in self.command_lines(data):
            self._handle(line)

    def _handle(self, line: bytes) -> None:
        try:
            address, command, _ = decode_line(line, lead=b"#")
        except ChecksumError:
            if line[1:3] == b"%02d" % self.address:
                self._reply("ER", "CHECKSUM")
            return
        except FrameError:
            return  # not a request: an instrument on a shared line stays silent
        if address != self.address:
            return
        if command == "ID":
            self._reply("ID", MODEL, self.serial, f"{self.resolution_arcsec:g}", f"{self.range_arcsec:g}")
        elif command == "RD":
            self._reply("RD", *self._reading())
        else:
            self._reply("ER", "BADCMD")

    def _reading(self) -> tuple[str, ...]:
        t = self.clock.now_s()
        psi = self.world.crank.phase_rad(t)
        tilt = np.array(table_tilt_rad(psi, self.world.twin, self.about_y, self.about_z), dtype=float) / ARCSEC_RAD
        tilt += self._rng.normal(0.0, self.noise_arcsec, 3)
        tilt = np.rint(tilt / self.resolution_arcsec) * self.resolution_arcsec
        status = 2 if self.faults.active(Fault.SIGNAL_LOSS) else 1 if np.any(np.abs(tilt) > self.range_arcsec) else 0
        tilt = np.clip(tilt, -self.range_arcsec, self.range_arcsec)
        self.readings += 1
        return format_reading(self.readings, ticks_of(t), tilt, status)

    def _reply(self, command: str, *fields: object) -> None:
        line = encode_line("!", self.address, command, *fields)
        if self.faults.take(Fault.GARBLE):
            line = garble(line[:-2]) + b"\r\n"
        elif self.faults.take(Fault.TRUNCATE):
            line = truncate(line)
        elif self.faults.take(Fault.CRC_ERROR):
            line = line[:-4] + b"%02X\r\n" % ((int(line[-4:-2], 16) + 1) % 256)
        self.send(line)
