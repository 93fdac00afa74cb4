"""What a station records: measurement points, raw streams, and the session that holds them.

The columns are those of the `piga-session/1` interchange format (physics.md).
Times t1_s, t2_s and Tm_s are measured from the window's opening edge; start_s
is session time when the window opened.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Literal

import numpy as np

from station import constants
from station.records import Field, RecordError, RecordType, declared
from station.validation import Check, in_range, settings, spec

PointKind = Literal["static", "vibration"]


# The station keys' ranges, declared once: the station file's [station] section and session.json's `station`
# object (piga-session/1) are checked against these.
STATION_FIELDS: tuple[Field, ...] = (
    Field("A0_m", "float64", "m", lo=0.0, hi=0.1, lo_open=True, doc="table displacement amplitude"),
    Field("latitude_deg", "float64", "deg", lo=-90.0, hi=90.0, doc="station latitude"),
    Field("g_mps2", "float64", "m/s^2", lo=9.7, hi=9.9, doc="local gravity"),
    Field("earth_rate_radps", "float64", "rad/s", lo=7.0e-5, hi=7.5e-5, doc="earth rotation rate"),
    Field("pulses_per_rev", "int64", "1/rev", lo=1, hi=2**31, doc="output pulses per revolution"),
)


def _declared_range(name: str) -> Check:
    f = next(f for f in STATION_FIELDS if f.name == name)
    return in_range(-math.inf if f.lo is None else f.lo, math.inf if f.hi is None else f.hi, lo_open=f.lo_open)


@settings
class StationInfo:
    """The station's geometry and constants: the `station` object of session.json, the station file's
    [station] section (drivers.config), the twin's station (station.twin.config); validated on construction."""

    A0_m: float = spec(_declared_range("A0_m"), default=constants.A0_M)
    latitude_deg: float = spec(_declared_range("latitude_deg"), default=constants.LATITUDE_DEG)
    g_mps2: float = spec(_declared_range("g_mps2"), default=constants.G_MPS2)
    earth_rate_radps: float = spec(_declared_range("earth_rate_radps"), default=constants.EARTH_RATE_RADPS)
    pulses_per_rev: int = spec(_declared_range("pulses_per_rev"), default=constants.PULSES_PER_REV)

    @property
    def latitude_rad(self) -> float:
        return math.radians(self.latitude_deg)

    @property
    def pulse_angle_rad(self) -> float:
        """One output pulse's precession angle, 2 pi / pulses_per_rev."""
        return 2.0 * math.pi / self.pulses_per_rev

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

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray | None]) -> RawStreams:
        """The streams of one point from its named arrays (the optional ones may be missing)."""
        t, z, pulses = (arrays.get(n) for n in RAW_REQUIRED)
        if t is None or z is None or pulses is None:
            missing = [n for n in RAW_REQUIRED if arrays.get(n) is None]
            raise ValueError(f"raw streams without {', '.join(missing)} (required: {', '.join(RAW_REQUIRED)})")
        return cls(t, z, pulses, arrays.get("pulse_dir"), arrays.get("reference_t"))


RAW_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(RawStreams))
RAW_REQUIRED: tuple[str, ...] = ("grating_t", "grating_z", "pulse_t")  # physics.md raw/; the rest optional


@dataclass
class Measurement:
    """Any other recorded measurement of a procedure (a grating stretch, a frequency run, a voltmeter reading).

    `key` is unique in its session; `values` are JSON scalars or lists, `arrays` numpy arrays.
    """

    key: str
    kind: str
    values: dict[str, Any] = field(default_factory=dict)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)

    def checked(self, record_type: RecordType | None = None) -> Measurement:
        """A typed copy, checked against its record type (given, else the one declared for its kind);
        RecordError names the measurement, the field, the value and what is allowed."""
        rt = record_type or declared(self.kind)
        where = f"measurement {self.key!r}"
        if rt is None:
            raise RecordError(where, "kind", self.kind, "a kind some method declares (station.records.declare)")
        return Measurement(
            self.key, self.kind, rt.check_values(self.values, where), rt.check_arrays(self.arrays, where)
        )


@dataclass
class Session:
    station: StationInfo
    points: list[PointRecord]
    notes: str = ""
    raw: Mapping[str, RawStreams] = field(default_factory=dict)  # point_id -> streams (read lazily from a store)
    meta: dict = field(default_factory=dict)
    measurements: list[Measurement] = field(default_factory=list)
    provenance: dict[str, Any] = field(default_factory=dict)  # station.provenance.PROVENANCE_KEYS
    record_types: list[RecordType] = field(default_factory=list)  # the declarations of the measurements' kinds
    results: list[dict[str, Any]] = field(default_factory=list)  # the analyses' results: {method, created_utc, result}

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
