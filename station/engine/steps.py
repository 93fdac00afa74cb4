"""The steps a procedure yields, and what each one means in a plan and in a run.

A procedure is a generator function `proc(params) -> Generator[Step, Any, R]`;
each step's result comes back into it (`record = yield MeasurePoint(...)`).
Every step knows two things:

- `plan(ctx)`: check itself against the station's limits (`raise ctx.fail(...)`
  naming the field, the value and what is allowed), update the nominal state,
  and return its estimated duration and a nominal result. Nothing moves.
- `run(ctx)`: do it through the station's drivers.

A step with a `key` records a measurement: the engine stores its result
durably before the procedure sees it, and on resume hands back the stored
result instead of measuring again. Lab engineers add steps for new devices by
subclassing `Step` next to their procedure; the engine needs no change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from station.engine.timing import TimingFault, capture_timing, cross_check
from station.records import Field, declare
from station.session import Measurement, PointRecord, RawStreams

if TYPE_CHECKING:
    from station.engine.context import PlanContext, RunContext


class Step:
    """Base of every step."""

    @property
    def key(self) -> str | None:
        """The measurement's id, unique in a session; None for a step that records nothing."""
        return None

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        raise NotImplementedError

    def run(self, ctx: RunContext) -> Any:
        raise NotImplementedError


@dataclass(frozen=True)
class Recorded:
    """A measured point as the engine stores it; the procedure receives `record`."""

    record: PointRecord
    raw: RawStreams | None = None


# A vibration window's grating stretch, recorded at its start, cross-checks the counter's
# reference crossings (physics.md integer-period timing): 0.4 s holds 4 periods at 10 Hz.
GRATING_CHECK_S = 0.4


@dataclass(frozen=True)
class MeasurePoint(Step):
    """Move the head, set the table, settle, count one window and record it (static if freq_hz == 0).

    Result: station.session.PointRecord with Tm, t1, t2, Np by integer-period timing capture.
    """

    point_id: str
    position_deg: float
    freq_hz: float
    preset_pulses: int
    settle_s: float = 5.0
    raw: bool = False  # also store the grating stretch and every pulse edge

    @property
    def key(self) -> str:
        return self.point_id

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        ctx.require("counter")
        ctx.check_position(self.position_deg)
        ctx.check_freq(self.freq_hz)
        m = ctx.model
        if not (isinstance(self.preset_pulses, int) and 0 < self.preset_pulses <= m.max_preset):
            raise ctx.fail("preset_pulses", self.preset_pulses, f"a whole number 1 .. {m.max_preset}")
        if not 0 <= self.settle_s <= 3600:
            raise ctx.fail("settle_s", self.settle_s, "0 .. 3600 s")
        dt = ctx.move_head(self.position_deg) + ctx.set_table(self.freq_hz) + self.settle_s
        start_s = ctx.state.t_s + dt
        tm_s = m.window_s(self.position_deg, self.preset_pulses)
        period_s = 1.0 / self.freq_hz if self.freq_hz else 0.0
        dt += tm_s + period_s + (GRATING_CHECK_S if self.freq_hz else 0.0)
        half = period_s / 2 if period_s else None
        record = PointRecord(
            self.point_id, ctx.state.sequence, start_s, self.position_deg, self.freq_hz,
            "vibration" if self.freq_hz else "static", self.preset_pulses, tm_s, half, half,
            round(tm_s * self.freq_hz) if period_s else None,
        )  # fmt: skip
        ctx.state.sequence += 1
        return dt, record

    def run(self, ctx: RunContext) -> Recorded:
        ctx.move_head(self.position_deg)
        ctx.set_table(self.freq_hz, self.settle_s)
        ctx.check_abort()
        vib = self.freq_hz != 0
        result, (g_t, g_z) = ctx.hw.measure_window(
            self.preset_pulses,
            stream_edges=self.raw,
            on_event=ctx.window_monitor(self.key, self.preset_pulses),
            grating_s=GRATING_CHECK_S if vib else 0.0,
            on_trace=ctx.trace_sink(),
        )
        timing = capture_timing(result.open_s, result.close_s, result.crossings_s, self.freq_hz)
        extra = (
            {k: f"{v:.9g}" for k, v in cross_check(result.crossings_s, g_t, g_z, self.freq_hz).items()} if vib else {}
        )
        record = PointRecord(
            self.point_id, ctx.sequence, result.open_s - ctx.t0_s, self.position_deg, self.freq_hz,
            "vibration" if vib else "static", result.pulses, timing.Tm_s, timing.t1_s, timing.t2_s, timing.Np, extra,
        )  # fmt: skip
        raw = None
        if self.raw:
            if result.edges_t_s is None:
                raise TimingFault(f"{self.key}: raw streams asked for, but the counter streamed no pulse edges")
            raw = RawStreams(
                g_t - result.open_s, g_z, result.edges_t_s - result.open_s, result.edges_dir,
                result.crossings_s - result.open_s,
            )  # fmt: skip
        return Recorded(record, raw)


@dataclass(frozen=True)
class MoveIndex(Step):
    """Move the indexing head (the table is brought to rest first). Result: the settled angle in deg."""

    position_deg: float

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        ctx.check_position(self.position_deg)
        return ctx.set_table(0.0) + ctx.move_head(self.position_deg), self.position_deg

    def run(self, ctx: RunContext) -> float:
        return ctx.move_head(self.position_deg)


@dataclass(frozen=True)
class SetVibration(Step):
    """Ramp the table to freq_hz (0 brings it to rest) and wait settle_s. Result: the drive's frequency in Hz."""

    freq_hz: float
    settle_s: float = 5.0

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        ctx.check_freq(self.freq_hz)
        return ctx.set_table(self.freq_hz) + self.settle_s, self.freq_hz

    def run(self, ctx: RunContext) -> float:
        return ctx.set_table(self.freq_hz, self.settle_s)


MOTION = declare(
    "motion",
    [Field("freq_hz", "float64", "Hz", lo=0.0, hi=100.0, doc="commanded table frequency"),
     Field("position_deg", "float64", "deg", nullable=True, doc="indexing head angle (null before any move)")],
    arrays=[Field("t_s", "float64", "s", doc="grating sample times, station time"),
            Field("z_m", "float64", "m", doc="table displacement (absolute grating)"),
            Field("reference_t_s", "float64", "s", doc="reference-mark crossings, station time")],
    doc="a stretch of the 5 kHz grating record and the reference crossings in it (seed 000 eq. 30, Table 5)",
)  # fmt: skip
FREQUENCY = declare(
    "frequency",
    [Field("commanded_hz", "float64", "Hz", lo=0.0, hi=100.0), Field("freq_hz", "float64", "Hz", lo=0.0),
     Field("stability", "float64", "", lo=0.0, doc="relative standard deviation of the periods"),
     Field("periods", "int64", "", lo=2, doc="consecutive periods timed")],
    arrays=[Field("periods_s", "float64", "s", lo=0.0, doc="the timed periods")],
    doc="frequency and stability from consecutive reference-mark periods (seed 000 Table 6)",
)  # fmt: skip


@dataclass(frozen=True)
class CaptureGrating(Step):
    """Record duration_s of the 5 kHz grating and the reference crossings in it (seed 000 eq. 30, Table 5).

    Result: Measurement of kind "motion" with arrays t_s, z_m and reference_t_s (station time) and
    values freq_hz (commanded), position_deg.
    """

    name: str
    duration_s: float

    @property
    def key(self) -> str:
        return self.name

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        ctx.require("grating")
        if not 0 < self.duration_s <= 600:
            raise ctx.fail("duration_s", self.duration_s, "0 .. 600 s")
        f = ctx.state.freq_hz
        t = np.arange(math.ceil(self.duration_s * 5000)) / 5000.0
        z = ctx.model.station.A0_m * np.sin(2 * np.pi * f * t)
        ref = np.arange(0.0, self.duration_s, 1.0 / f) if f else np.zeros(0)
        values = {"freq_hz": f, "position_deg": ctx.state.position_deg}
        return self.duration_s, Measurement(self.key, "motion", values, {"t_s": t, "z_m": z, "reference_t_s": ref})

    def run(self, ctx: RunContext) -> Measurement:
        m = ctx.hw.capture_motion(self.duration_s)
        values = {"freq_hz": ctx.freq_hz, "position_deg": ctx.position_deg}
        return Measurement(self.key, "motion", values, {"t_s": m.t_s, "z_m": m.z_m, "reference_t_s": m.reference_t_s})


@dataclass(frozen=True)
class MeasureFrequency(Step):
    """Time `periods` reference-mark periods (seed 000 Table 6) as a measurement of frequency and stability."""

    name: str
    periods: int = 100

    @property
    def key(self) -> str:
        return self.name

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        f = ctx.state.freq_hz
        if f == 0:
            raise ctx.fail("freq_hz", 0.0, "a vibrating table (reference crossings are timed)")
        if not 2 <= self.periods <= 100_000:
            raise ctx.fail("periods", self.periods, "2 .. 100000")
        values = {"commanded_hz": f, "freq_hz": f, "stability": 0.0, "periods": self.periods}
        return (self.periods + 1) / f, Measurement(
            self.key, "frequency", values, {"periods_s": np.full(self.periods, 1 / f)}
        )

    def run(self, ctx: RunContext) -> Measurement:
        est = ctx.hw.measure_frequency(self.periods)
        values = {"commanded_hz": ctx.freq_hz, "freq_hz": est.f_hz, "stability": est.sigma_rel,
                  "periods": self.periods}  # fmt: skip
        return Measurement(self.key, "frequency", values, {"periods_s": np.asarray(est.periods_s)})


@dataclass(frozen=True)
class Checkpoint(Step):
    """A safe point: a pause takes effect here."""

    label: str = ""

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        return 0.0, None

    def run(self, ctx: RunContext) -> None:
        ctx.safe_point()


@dataclass(frozen=True)
class Note(Step):
    """A line in the session's event log."""

    message: str

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        return 0.0, None

    def run(self, ctx: RunContext) -> None:
        ctx.event("note", self.message)


@dataclass(frozen=True)
class Wait(Step):
    """Wait duration_s of station time with the station as it is (thermal soak, drift tests)."""

    duration_s: float
    reason: str = ""

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        if not 0 <= self.duration_s <= 7 * 86400:
            raise ctx.fail("duration_s", self.duration_s, "0 .. 604800 s")
        return self.duration_s, None

    def run(self, ctx: RunContext) -> None:
        ctx.wait_s(self.duration_s)


@dataclass(frozen=True)
class OperatorAction(Step):
    """Ask the operator to do something by hand and wait for their confirmation (a fixture pose, a cable).

    `action` says the same thing to machines: what a simulated operator does to the simulated
    world (e.g. {"fixture_pose": 3}); a real operator reads `message` on the panel or console.
    """

    message: str
    action: tuple[tuple[str, Any], ...] = ()
    expected_s: float = 300.0

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        if not 0 <= self.expected_s <= 86400:
            raise ctx.fail("expected_s", self.expected_s, "0 .. 86400 s")
        return self.expected_s, None

    def run(self, ctx: RunContext) -> Measurement | None:
        """None; a subclass may return the record of what was done (RemoveMass)."""
        ctx.ask_operator(self.message, dict(self.action))
        return None
