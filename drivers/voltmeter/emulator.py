"""Emulator of the precision voltmeter (protocol in drivers.voltmeter.protocol), wired to the tumbled accelerometer.

The input is the output of a pendulous accelerometer on the indexing head: one model per
world (`world.shared("pendulous_accelerometer", ...)`, a `TumbledAccelerometer`), evaluated by
station.twin.pendulous_accelerometer (seed 001 eqs. 1 and 4) at the head's angle
(`world.index_position_deg`) and the chamber's product temperature
(`world.shared("temperature_chamber", ...)`, ambient when the station has no chamber). The
accelerometer follows every head command (`world.on_head_move`), so that its hysteresis branch follows the
path the head turned whether or not the voltmeter's line was in use (an idle sim:// line is never polled).

READ? integrates in station time: the reply goes out once `drivers.voltmeter.protocol.reading_s` has
passed; commands that arrive meanwhile wait, as on the instrument. Each reading adds the
accelerometer's white noise over its aperture and the meter's own (0.15 ppm of range at 10 PLC).

Faults: NO_ANSWER (ignore `count` commands), GARBLE / TRUNCATE (next reply), DISCONNECT, and
VoltmeterFault.OVERLOAD (the next READ? reads +9.9E37).
"""

from __future__ import annotations

import enum
import math
import threading
from collections import deque
from typing import Any

import numpy as np

from drivers.pty_link import Fault, PtyEmulator, garble, truncate
from drivers.temperature_chamber.emulator import ChamberThermal
from drivers.voltmeter import protocol as vm
from station.twin.pendulous_accelerometer import AccelerometerModel, branch_after_move, noise_sigma_g, output_v

METER_NOISE_OF_RANGE = 0.15e-6  # rms at 10 PLC, scaling as 1/sqrt(NPLC)
IDENTITY = "KEITHLEY INSTRUMENTS INC.,MODEL 2002,4230517,A20  /A02"
ERROR_QUEUE = 10


class VoltmeterFault(enum.Enum):
    OVERLOAD = "overload"


class TumbledAccelerometer:
    """The accelerometer on the indexing head inside the chamber: its model, launch offset and hysteresis branch."""

    def __init__(self, world: Any, model: AccelerometerModel | None = None) -> None:
        self.world = world
        self.model = model or AccelerometerModel()
        self.rng = np.random.default_rng(world.rng.integers(2**63))
        self.launch_g = float(self.rng.normal(0.0, self.model.launch_sigma_g))  # k0L, drawn at power-up
        self._lock = threading.Lock()
        self._theta_rad = math.radians(world.index_position_deg(world.clock.now_s()))
        self.branch = 0.0
        world.on_head_move(self.follow)

    def set_model(self, model: AccelerometerModel) -> None:
        """Another instrument from now on (tests), keeping the launch offset drawn at power-up."""
        self.model = model

    def follow(self, t_s: float) -> float:
        """Track the head; the angle in rad."""
        theta = math.radians(self.world.index_position_deg(t_s))
        with self._lock:
            if theta != self._theta_rad:
                self.branch = branch_after_move(self._theta_rad, theta, self.branch)
                self._theta_rad = theta
        return theta

    def temperature_c(self, t_s: float) -> float:
        return self.world.shared("temperature_chamber", ChamberThermal).temperature_c(t_s)

    def bias_extra_g(self, t_s: float) -> float:
        """k0L + k0D t (seed 001 eq. 3), t from power-up."""
        return self.launch_g + self.model.drift_g_per_s * t_s

    def sample_v(self, t_mid_s: float, aperture_s: float, n: int) -> np.ndarray:
        """n readings of the output around t_mid_s, each averaged over aperture_s."""
        m = self.model
        theta = self.follow(t_mid_s)
        clean = output_v(m, theta, self.temperature_c(t_mid_s), self.branch, self.bias_extra_g(t_mid_s))
        return clean + m.scale_v_per_g * self.rng.normal(0.0, noise_sigma_g(m, aperture_s), n)


def accelerometer(world: Any) -> TumbledAccelerometer:
    """The world's accelerometer (made on first use)."""
    return world.shared("pendulous_accelerometer", lambda: TumbledAccelerometer(world))


class VoltmeterEmulator(PtyEmulator):
    name = "voltmeter-emulator"
    supported_faults = frozenset({Fault.NO_ANSWER, Fault.GARBLE, Fault.TRUNCATE, Fault.DISCONNECT,
                                  VoltmeterFault.OVERLOAD})  # fmt: skip

    def __init__(self, world: Any, *, baud: int = 19_200, line_hz: float = 50.0, **kw: Any) -> None:
        super().__init__(world.clock, baud=baud, **kw)
        self.world = world
        self.line_hz = line_hz
        self.accelerometer = accelerometer(world)
        self.rng = np.random.default_rng(world.rng.integers(2**63))
        self._queue: deque[str] = deque()  # commands waiting for a READ? under way
        self._busy_until_s: float | None = None
        self.errors: deque[str] = deque()
        self.commands: list[str] = []  # log, for tests
        self._reset()

    def _reset(self) -> None:
        self.range_v, self.nplc, self.samples = 20.0, 1.0, 1

    def _error(self, code: int, text: str) -> None:
        if len(self.errors) >= ERROR_QUEUE:
            self.errors[-1] = '-350,"Queue overflow"'
            return
        self.errors.append(f'{code},"{text}"')

    # ---- input

    def on_bytes(self, data: bytes) -> None:
        for line in self.command_lines(data):
            text = line.decode("ascii", "replace")
            self._queue.extend(c.strip() for c in text.split(";") if c.strip())
        self._run_queue()

    def on_poll(self, now_s: float) -> None:
        if self._busy_until_s is not None and now_s >= self._busy_until_s:
            self._busy_until_s = None
            self._reply(self._readings(now_s))
        self._run_queue()

    def next_due_s(self, now_s: float) -> float:
        """A READ? under way is due when its integration ends; an idle meter only answers commands."""
        return math.inf if self._busy_until_s is None else self._busy_until_s

    def _run_queue(self) -> None:
        while self._queue and self._busy_until_s is None:
            self._handle(self._queue.popleft())

    def _reply(self, text: str) -> None:
        line = text.encode("ascii") + b"\n"
        if self.faults.take(Fault.GARBLE):
            line = garble(line)
        elif self.faults.take(Fault.TRUNCATE):
            line = truncate(line)
        self.send(line)

    # ---- SCPI

    def _handle(self, command: str) -> None:
        self.commands.append(command)
        path, arg = vm.command_path(command)
        match path:
            case "*IDN?":
                self._reply(IDENTITY)
            case "*RST":
                self._reset()
            case "*CLS":
                self.errors.clear()
            case "*OPC?":
                self._reply("1")
            case "SYST:ERR?":
                self._reply(self.errors.popleft() if self.errors else '0,"No error"')
            case "CONF:VOLT:DC":
                if arg:
                    self._set_range(arg)
            case "VOLT:DC:RANG" | "VOLT:DC:NPLC" | "SAMP:COUN":
                self._set(path, arg)
            case "VOLT:DC:RANG?":
                self._reply(f"{self.range_v:+.6E}")
            case "VOLT:DC:NPLC?":
                self._reply(f"{self.nplc:+.6E}")
            case "SAMP:COUN?":
                self._reply(str(self.samples))
            case "READ?":
                self._busy_until_s = self.clock.now_s() + vm.reading_s(self.nplc, self.samples, self.line_hz)
            case _:
                self._error(-113, "Undefined header")

    def _set(self, path: str, arg: str) -> None:
        try:
            value = float(arg)
        except ValueError:
            self._error(-104, "Data type error")
            return
        if path == "VOLT:DC:RANG":
            self._set_range(arg)
        elif path == "VOLT:DC:NPLC" and vm.NPLC_LIMITS[0] <= value <= vm.NPLC_LIMITS[1]:
            self.nplc = value
        elif path == "SAMP:COUN" and value.is_integer() and 1 <= value <= vm.MAX_SAMPLES:
            self.samples = int(value)
        else:
            self._error(-222, "Data out of range")

    def _set_range(self, arg: str) -> None:
        try:
            value = float(arg)
        except ValueError:
            self._error(-104, "Data type error")
            return
        fits = [r for r in vm.RANGES_V if r >= abs(value)]  # the instrument picks the range that holds the value
        if not fits:
            self._error(-222, "Data out of range")
            return
        self.range_v = fits[0]

    def _readings(self, end_s: float) -> str:
        period_s = vm.CONVERSIONS_PER_READING * self.nplc / self.line_hz
        aperture_s = self.nplc / self.line_hz
        mid_s = end_s - self.samples * period_s / 2
        volts = self.accelerometer.sample_v(mid_s, aperture_s, self.samples)
        volts += self.rng.normal(0.0, METER_NOISE_OF_RANGE * self.range_v * math.sqrt(10.0 / self.nplc), volts.size)
        volts[np.abs(volts) > vm.OVERRANGE * self.range_v] = vm.OVERLOAD_V
        if self.faults.take(VoltmeterFault.OVERLOAD):
            volts[:] = vm.OVERLOAD_V
        return vm.format_readings(volts)
