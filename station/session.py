"""What a station records: measurement points, raw streams, and the session that holds them.

The columns are those of the `piga-session/1` interchange format (physics.md).
Times t1_s, t2_s and Tm_s are measured from the window's opening edge; start_s
is session time when the window opened.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from station import constants

PointKind = Literal["static", "vibration"]


@dataclass(frozen=True)
class StationInfo:
    """The `station` object of session.json."""

    A0_m: float = constants.A0_M
    latitude_deg: float = constants.LATITUDE_DEG
    g_mps2: float = constants.G_MPS2
    earth_rate_radps: float = constants.EARTH_RATE_RADPS
    pulses_per_rev: int = constants.PULSES_PER_REV

    def amplitude_ratio(self, freq_hz):
        """a = A0 (2 pi f)^2 / g."""
        w = 2.0 * np.pi * np.asarray(freq_hz, dtype=float)
        return self.A0_m * w * w / self.g_mps2


@dataclass(frozen=True)
class PointRecord:
    point_id: str
    sequence: int
    start_s: float
    position_deg: float
    freq_hz: float
    kind: PointKind
    pulses: int
    Tm_s: float
    t1_s: float | None = None
    t2_s: float | None = None
    Np: int | None = None
    extra: dict[str, str] = field(default_factory=dict)

    def measured_rate_radps(self, pulses_per_rev: int) -> float:
        """wbar = sign * 2 pi |P| / (pulses_per_rev Tm) (physics.md; seed 000 eq. 17)."""
        return 2.0 * math.pi * self.pulses / (pulses_per_rev * self.Tm_s)


@dataclass
class RawStreams:
    """Raw records of one point, times in seconds from the window's opening edge."""

    grating_t: np.ndarray
    grating_z: np.ndarray
    pulse_t: np.ndarray
    pulse_dir: np.ndarray | None = None
    reference_t: np.ndarray | None = None


@dataclass
class Measurement:
    """Any other recorded measurement of a procedure (a grating stretch, a frequency run, a voltmeter reading).

    `key` is unique in its session; `values` are JSON scalars or lists, `arrays` numpy arrays.
    """

    key: str
    kind: str
    values: dict[str, Any] = field(default_factory=dict)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class Session:
    station: StationInfo
    points: list[PointRecord]
    notes: str = ""
    raw: dict[str, RawStreams] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    measurements: list[Measurement] = field(default_factory=list)

    def rates_radps(self) -> np.ndarray:
        return np.array([p.measured_rate_radps(self.station.pulses_per_rev) for p in self.points])

    def select(self, kind: PointKind) -> list[PointRecord]:
        return [p for p in self.points if p.kind == kind]


def point_table(points: Sequence[PointRecord]) -> dict[str, np.ndarray]:
    """Columns of the points as arrays (NaN / -1 where a static point has no t1, t2, Np)."""
    return {
        "position_deg": np.array([p.position_deg for p in points], dtype=float),
        "freq_hz": np.array([p.freq_hz for p in points], dtype=float),
        "Tm_s": np.array([p.Tm_s for p in points], dtype=float),
        "t1_s": np.array([np.nan if p.t1_s is None else p.t1_s for p in points], dtype=float),
        "t2_s": np.array([np.nan if p.t2_s is None else p.t2_s for p in points], dtype=float),
        "Np": np.array([-1 if p.Np is None else p.Np for p in points], dtype=np.int64),
        "start_s": np.array([p.start_s for p in points], dtype=float),
    }
