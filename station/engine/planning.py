"""Validation and dry run: a procedure's steps checked against the station's limits and timed.

The procedure runs against a nominal model of the station (no hardware): each
step is checked (frequency, acceleration amplitude A0 (2 pi f)^2 / g,
indexing range, preset count) and given an estimated duration; measurement
steps return nominal points so the procedure can go on. Nothing moves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from station.engine.registry import ProcedureSpec
from station.engine.steps import (
    CaptureGrating,
    Checkpoint,
    MeasureFrequency,
    MeasurePoint,
    MoveIndex,
    Note,
    SetVibration,
    Step,
)
from station.session import PointRecord, StationInfo


class ValidationError(ValueError):
    """A step that the station cannot or must not do: names the step, the field, the value, the limit."""


@dataclass(frozen=True)
class StationModel:
    """What planning knows of the station: limits, motion speeds, and the instrument's nominal rate."""

    station: StationInfo = field(default_factory=StationInfo)
    freq_min_hz: float = 0.1
    freq_max_hz: float = 10.0
    accel_min_g: float = 0.001
    accel_max_g: float = 12.5
    index_min_deg: float = -720.0
    index_max_deg: float = 720.0
    index_speed_deg_s: float = 20.0
    index_settle_s: float = 0.5
    ramp_hz_per_s: float = 2.0
    max_preset: int = 2**31 - 1
    k0_nominal_radps: float = 1.5e-4
    kz_nominal_radps_per_g: float = 0.56

    def accel_g(self, freq_hz: float) -> float:
        return self.station.A0_m * (2 * math.pi * freq_hz) ** 2 / self.station.g_mps2

    def window_s(self, position_deg: float, preset_pulses: int) -> float:
        """Nominal Tm = 2 pi P / (16384 |k0 + kz cos theta|) (physics.md, seed 003 test time)."""
        rate = abs(self.k0_nominal_radps + self.kz_nominal_radps_per_g * math.cos(math.radians(position_deg)))
        return 2 * math.pi * preset_pulses / (self.station.pulses_per_rev * max(rate, 1e-12))


@dataclass
class PlannedStep:
    index: int
    step: Step
    estimate_s: float
    start_s: float


@dataclass
class Plan:
    procedure: str
    steps: list[PlannedStep]

    @property
    def total_s(self) -> float:
        return sum(s.estimate_s for s in self.steps)

    @property
    def points(self) -> list[PlannedStep]:
        return [s for s in self.steps if isinstance(s.step, MeasurePoint)]

    def point_estimates(self) -> dict[str, float]:
        """Estimated seconds per point, including the moves and settling that lead to it."""
        out, acc = {}, 0.0
        for s in self.steps:
            acc += s.estimate_s
            if isinstance(s.step, MeasurePoint):
                out[s.step.point_id] = acc
                acc = 0.0
        return out


@dataclass
class _State:
    position_deg: float = 0.0
    freq_hz: float = 0.0
    t_s: float = 0.0
    sequence: int = 0
    seen: set[str] = field(default_factory=set)


def _fail(i: int, step: Step, field_: str, value: Any, allowed: str) -> ValidationError:
    name = type(step).__name__
    pid = f" ({step.point_id})" if isinstance(step, MeasurePoint) else ""
    return ValidationError(f"step {i} {name}{pid}: {field_} = {value!r} is not allowed: {allowed}")


def _check_freq(m: StationModel, i: int, step: Step, f: float) -> None:
    if f == 0:
        return
    if not (math.isfinite(f) and m.freq_min_hz <= f <= m.freq_max_hz):
        raise _fail(i, step, "freq_hz", f, f"0 (static) or {m.freq_min_hz:g} .. {m.freq_max_hz:g} Hz")
    a = m.accel_g(f)
    if not m.accel_min_g <= a <= m.accel_max_g:
        raise _fail(i, step, "acceleration amplitude", round(a, 4), f"{m.accel_min_g:g} .. {m.accel_max_g:g} g")


def _check_position(m: StationModel, i: int, step: Step, p: float) -> None:
    if not (math.isfinite(p) and m.index_min_deg <= p <= m.index_max_deg):
        raise _fail(i, step, "position_deg", p, f"{m.index_min_deg:g} .. {m.index_max_deg:g} deg")


def _move_s(m: StationModel, st: _State, position_deg: float) -> float:
    d = abs(position_deg - st.position_deg)
    return d / m.index_speed_deg_s + m.index_settle_s if d else 0.0


def _ramp_s(m: StationModel, st: _State, freq_hz: float) -> float:
    return abs(freq_hz - st.freq_hz) / m.ramp_hz_per_s


def _simulate(m: StationModel, st: _State, i: int, step: Step) -> tuple[float, Any]:
    """Check a step, estimate its duration, update the nominal state, return a nominal result."""
    if isinstance(step, MeasurePoint):
        if step.point_id in st.seen:
            raise _fail(i, step, "point_id", step.point_id, "a point_id used once per session")
        st.seen.add(step.point_id)
        _check_position(m, i, step, step.position_deg)
        _check_freq(m, i, step, step.freq_hz)
        if not (isinstance(step.preset_pulses, int) and 0 < step.preset_pulses <= m.max_preset):
            raise _fail(i, step, "preset_pulses", step.preset_pulses, f"a whole number 1 .. {m.max_preset}")
        moving = st.freq_hz != 0 and step.position_deg != st.position_deg
        dt = (_ramp_s(m, st, 0.0) if moving else 0.0) + _move_s(m, st, step.position_deg)
        if moving:
            st.freq_hz = 0.0
        dt += _ramp_s(m, st, step.freq_hz) + step.settle_s
        tm = m.window_s(step.position_deg, step.preset_pulses)
        period = 1.0 / step.freq_hz if step.freq_hz else 0.0
        start = st.t_s + dt
        dt += tm + period  # the window, then up to one period to the closing crossing
        st.position_deg, st.freq_hz = step.position_deg, step.freq_hz
        kind = "vibration" if step.freq_hz else "static"
        rec = PointRecord(
            step.point_id, st.sequence, start, step.position_deg, step.freq_hz, kind, step.preset_pulses, tm,
            period / 2 if period else None, period / 2 if period else None,
            round(tm * step.freq_hz) if period else None,
        )  # fmt: skip
        st.sequence += 1
        return dt, rec
    if isinstance(step, MoveIndex):
        _check_position(m, i, step, step.position_deg)
        if st.freq_hz != 0 and step.position_deg != st.position_deg:
            raise _fail(i, step, "position_deg", step.position_deg, "no head move while the table vibrates")
        dt = _move_s(m, st, step.position_deg)
        st.position_deg = step.position_deg
        return dt, step.position_deg
    if isinstance(step, SetVibration):
        _check_freq(m, i, step, step.freq_hz)
        dt = _ramp_s(m, st, step.freq_hz) + step.settle_s
        st.freq_hz = step.freq_hz
        return dt, step.freq_hz
    if isinstance(step, CaptureGrating):
        if not 0 < step.duration_s <= 3600:
            raise _fail(i, step, "duration_s", step.duration_s, "0 .. 3600 s")
        n = int(step.duration_s * 5000)
        return step.duration_s, (st.t_s + 2e-4 * _arange(n), _zeros(n))
    if isinstance(step, MeasureFrequency):
        if st.freq_hz == 0:
            raise _fail(i, step, "freq_hz", 0.0, "the table must vibrate to time reference crossings")
        return (step.periods + 1) / st.freq_hz, _nominal_frequency(st.freq_hz, step.periods)
    if isinstance(step, Checkpoint | Note):
        return 0.0, None
    raise ValidationError(f"step {i}: {step!r} is not a step the engine knows")


def _arange(n: int):
    import numpy as np

    return np.arange(n, dtype=float)


def _zeros(n: int):
    import numpy as np

    return np.zeros(n)


def _nominal_frequency(freq_hz: float, periods: int):
    import numpy as np

    from drivers.reference_marks import FrequencyEstimate

    return FrequencyEstimate(freq_hz, 0.0, np.full(periods, 1.0 / freq_hz))


def plan_procedure(spec: ProcedureSpec, params: dict[str, Any], model: StationModel) -> Plan:
    """Validate every step and estimate its duration, without hardware."""
    gen = spec.func(params)
    st = _State()
    steps: list[PlannedStep] = []
    result: Any = None
    i = 0
    try:
        step = gen.send(None)
        while True:
            dt, result = _simulate(model, st, i, step)
            steps.append(PlannedStep(i, step, dt, st.t_s))
            st.t_s += dt
            i += 1
            step = gen.send(result)
    except StopIteration:
        pass
    return Plan(spec.name, steps)
