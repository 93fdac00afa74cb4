"""The steps a procedure yields. The engine interprets them three ways: validate, estimate, run.

A procedure is a generator function `proc(params) -> Generator[Step, Any, R]`:
each yielded step comes back as the step's result (`result = yield step`).
`MeasurePoint` is the workhorse: move the head, set the table, settle, count
one window and record the point durably; on resume a point already stored is
not measured again.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MeasurePoint:
    """One measurement point: static if freq_hz == 0. Result: station.session.PointRecord."""

    point_id: str
    position_deg: float
    freq_hz: float
    preset_pulses: int
    settle_s: float = 5.0
    raw: bool = False  # also record the grating stretch and every pulse edge


@dataclass(frozen=True)
class MoveIndex:
    """Move the indexing head (the table must be at rest). Result: settled position in deg."""

    position_deg: float


@dataclass(frozen=True)
class SetVibration:
    """Ramp the table to freq_hz (0 stops it) and wait settle_s. Result: measured frequency in Hz."""

    freq_hz: float
    settle_s: float = 5.0


@dataclass(frozen=True)
class CaptureGrating:
    """Record duration_s of the 5 kHz grating. Result: (t_s, z_m) arrays."""

    duration_s: float


@dataclass(frozen=True)
class MeasureFrequency:
    """Time `periods` reference crossings (seed 000 6.1.2). Result: drivers FrequencyEstimate."""

    periods: int = 10


@dataclass(frozen=True)
class Checkpoint:
    """A safe point: pause takes effect here; telemetry reports progress."""

    label: str = ""


@dataclass(frozen=True)
class Note:
    """A line in the session's event log. Result: None."""

    message: str


Step = MeasurePoint | MoveIndex | SetVibration | CaptureGrating | MeasureFrequency | Checkpoint | Note
