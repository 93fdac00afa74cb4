"""What a step sees: the station as planning imagines it (PlanContext) and the running engine (RunContext).

A step plans itself against `PlanContext` (the station's model, the nominal state,
checks that name the field, value and what is allowed) and runs itself through
`RunContext` (the engine: hardware, clock, table and head, events, safe points).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from station import constants
from station.clock import Clock
from station.engine.protocols import Event, StationHardware
from station.errors import InputError
from station.session import StationInfo


class Keyed(Protocol):
    """A step as planning names it: by its measurement key, if it has one."""

    @property
    def key(self) -> str | None: ...


class ValidationError(InputError):
    """A step that the station cannot or must not do."""


@dataclass(frozen=True)
class StationModel:
    """What planning knows of the station: limits, motion speeds, devices, the instrument's nominal rate."""

    station: StationInfo = field(default_factory=StationInfo)
    freq_min_hz: float = 0.1
    freq_max_hz: float = 10.0
    accel_min_g: float = 0.001
    accel_max_g: float = 12.5
    ramp_hz_per_s: float = 2.0
    index_min_deg: float = -720.0
    index_max_deg: float = 720.0
    index_speed_deg_s: float = 10.0
    index_settle_s: float = 2.0
    max_preset: int = 2**31 - 1
    k0_nominal_radps: float = constants.K0_RADPS
    kz_nominal_radps_per_g: float = constants.KZ_RADPS_PER_G
    devices: frozenset[str] = frozenset({"servo", "grating", "reference", "counter", "indexing_head"})
    sections: dict[str, Any] = field(default_factory=dict)  # config sections of further devices, by name

    def section(self, device: str) -> Any:
        """The config section (limits, speeds) of a further device; KeyError if the station has none."""
        return self.sections[device]

    def accel_g(self, freq_hz: float) -> float:
        """A0 (2 pi f)^2 / g, the table's acceleration amplitude."""
        return self.station.A0_m * (2 * math.pi * freq_hz) ** 2 / self.station.g_mps2

    def nominal_rate_radps(self, position_deg: float) -> float:
        """k0 + kz cos(theta): the static output rate (physics.md, seed 003)."""
        return self.k0_nominal_radps + self.kz_nominal_radps_per_g * math.cos(math.radians(position_deg))

    def window_s(self, position_deg: float, preset_pulses: int) -> float:
        """Nominal Tm = 2 pi P / (16384 |wbar|) (physics.md; seed 003 test time)."""
        rate = max(abs(self.nominal_rate_radps(position_deg)), 1e-12)
        return 2 * math.pi * preset_pulses / (self.station.pulses_per_rev * rate)


@dataclass
class NominalState:
    """The station as planning imagines it between steps."""

    position_deg: float = 0.0
    freq_hz: float = 0.0
    t_s: float = 0.0
    sequence: int = 0
    keys: set[str] = field(default_factory=set)
    devices: dict[str, Any] = field(default_factory=dict)  # nominal state of other devices, by name


@dataclass
class PlanContext:
    """What a step's `plan` sees: the model, the nominal state, and helpers that check and time motion."""

    model: StationModel
    state: NominalState
    index: int = 0
    step: Keyed | None = None  # the step being planned

    def fail(self, field_: str, value: Any, allowed: str) -> ValidationError:
        step = self.step
        key = f" ({step.key})" if step is not None and step.key else ""
        name = type(step).__name__ if step is not None else "step"
        return ValidationError(f"step {self.index} {name}{key}: {field_} = {value!r} is not allowed: {allowed}")

    def require(self, device: str) -> Any:
        """The config section of a further device the step needs (its config section, None for core devices)."""
        if device not in self.model.devices:
            raise self.fail("device", device, f"a device of this station: {', '.join(sorted(self.model.devices))}")
        return self.model.sections.get(device)

    def claim(self, key: str) -> None:
        """Reserve a measurement key; a key is used once per session."""
        if key in self.state.keys:
            raise self.fail("key", key, "a measurement key used once per session")
        self.state.keys.add(key)

    def check_freq(self, freq_hz: float) -> None:
        m = self.model
        if freq_hz == 0:
            return
        self.require("servo")  # a station without a vibration table (drivers.config TABLE_SECTIONS)
        if not (math.isfinite(freq_hz) and m.freq_min_hz <= freq_hz <= m.freq_max_hz):
            raise self.fail("freq_hz", freq_hz, f"0 (static) or {m.freq_min_hz:g} .. {m.freq_max_hz:g} Hz")
        a = m.accel_g(freq_hz)
        if not m.accel_min_g <= a <= m.accel_max_g:
            raise self.fail("acceleration amplitude", round(a, 4), f"{m.accel_min_g:g} .. {m.accel_max_g:g} g")

    def check_position(self, position_deg: float) -> None:
        m = self.model
        if not (math.isfinite(position_deg) and m.index_min_deg <= position_deg <= m.index_max_deg):
            raise self.fail("position_deg", position_deg, f"{m.index_min_deg:g} .. {m.index_max_deg:g} deg")

    def set_table(self, freq_hz: float) -> float:
        """Ramp time to freq_hz; the nominal table follows."""
        dt = abs(freq_hz - self.state.freq_hz) / self.model.ramp_hz_per_s
        self.state.freq_hz = freq_hz
        return dt

    def move_head(self, position_deg: float) -> float:
        """Ramp-down (the head never moves under vibration), travel and settling time; the nominal head follows."""
        distance = abs(position_deg - self.state.position_deg)
        if not distance:
            return 0.0
        dt = self.set_table(0.0) + distance / self.model.index_speed_deg_s + self.model.index_settle_s
        self.state.position_deg = position_deg
        return dt


class RunContext(Protocol):
    """The running engine as a step sees it (station.engine.runner.Engine implements it)."""

    hw: StationHardware
    clock: Clock
    position_deg: float | None
    freq_hz: float
    t0_s: float
    sequence: int

    def publish(self, topic: str, msg: dict) -> None: ...

    def check_abort(self) -> None: ...

    def safe_point(self) -> None: ...

    def event(self, kind: str, message: str, level: str = "info") -> None: ...

    def set_table(self, freq_hz: float, settle_s: float = 0.0) -> float: ...

    def move_head(self, position_deg: float) -> float: ...

    def ask_operator(self, message: str, action: dict) -> None: ...

    def wait_s(self, duration_s: float) -> None: ...

    def window_monitor(self, key: str, preset_pulses: int) -> Callable[[Event], None]: ...

    def trace_sink(self) -> Callable | None: ...
