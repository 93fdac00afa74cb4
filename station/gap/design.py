"""A recorded session as arrays, checked against the twin it is compared with.

Bad input is refused with a clear message (issue 3, point 8): here a session
from another station geometry, an empty one, or vibration points without
timing capture; too few points for the calibrated coefficients in
station.gap.api.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from station.errors import InputError
from station.session import PointRecord, Session
from station.twin.config import TwinConfig

# Relative tolerance on the station geometry of session.json against the twin's.
GEOMETRY_RTOL = 1e-6


class GapInputError(InputError):
    """The session cannot be compared with this twin (geometry, content or size)."""


@dataclass(frozen=True)
class PointDesign:
    """Columns of a session's points; theta in rad, times in s, rates in rad/s."""

    point_ids: tuple[str, ...]
    theta_rad: np.ndarray
    position_deg: np.ndarray
    freq_hz: np.ndarray  # commanded, 0 for static
    vib: np.ndarray
    Tm_s: np.ndarray
    t1_s: np.ndarray
    t2_s: np.ndarray
    Np: np.ndarray
    start_s: np.ndarray
    sequence: np.ndarray
    rate_radps: np.ndarray
    pos_index: np.ndarray
    positions_deg: np.ndarray  # unique positions, pos_index indexes into it

    @property
    def n_points(self) -> int:
        return int(self.theta_rad.size)

    @property
    def level_index(self) -> np.ndarray:
        """Index of each point's free static level: one bias k0 for the whole session (station.gap.forward)."""
        return np.zeros(self.n_points, dtype=np.int64)

    @property
    def n_levels(self) -> int:
        return 1

    @property
    def position_rad(self) -> np.ndarray:
        return np.radians(self.positions_deg)

    @property
    def tau_s(self) -> np.ndarray:
        """Recorded period identity t2 - t1 + Tm - Np T_cmd (0 for static points)."""
        tau = np.zeros(self.n_points)
        v = self.vib
        tau[v] = self.t2_s[v] - self.t1_s[v] + self.Tm_s[v] - self.Np[v] / self.freq_hz[v]
        return tau

    @classmethod
    def from_session(cls, session: Session) -> PointDesign:
        """The session's points as columns; raises GapInputError on an empty session or untimed vibration."""
        pts = session.points
        _check_points(pts)
        pos_deg = _column(pts, "position_deg")
        uniq, index = np.unique(np.round(pos_deg, 9), return_inverse=True)
        return cls(
            point_ids=tuple(p.point_id for p in pts),
            theta_rad=np.radians(pos_deg),
            position_deg=pos_deg,
            freq_hz=_column(pts, "freq_hz"),
            vib=np.array([p.kind == "vibration" for p in pts]),
            Tm_s=_column(pts, "Tm_s"),
            t1_s=_column(pts, "t1_s"),
            t2_s=_column(pts, "t2_s"),
            Np=_column(pts, "Np", np.int64, 0),
            start_s=_column(pts, "start_s"),
            sequence=_column(pts, "sequence", np.int64),
            rate_radps=session.rates_radps(),
            pos_index=index,
            positions_deg=uniq,
        )


def _check_points(pts: Sequence[PointRecord]) -> None:
    """Refuse an empty session, and vibration points without timing capture (t1, t2, Np)."""
    if not pts:
        raise GapInputError("the session has no points")
    bad = [p.point_id for p in pts if p.kind == "vibration" and (p.t1_s is None or p.t2_s is None or p.Np is None)]
    if bad:
        raise GapInputError(f"vibration point(s) without timing capture (t1, t2, Np): {', '.join(bad[:5])}")


def _column(pts: Sequence[PointRecord], attr: str, dtype: type = float, missing: float = math.nan) -> np.ndarray:
    """One field of every point as an array; `missing` where a point has none (a static point's timing)."""
    return np.array([missing if (v := getattr(p, attr)) is None else v for p in pts], dtype=dtype)


def check_geometry(session: Session, cfg: TwinConfig) -> None:
    """Refuse a session recorded on a station whose geometry differs from the twin's."""
    s, t = session.station, cfg.station
    diffs = []
    for key in ("A0_m", "latitude_deg", "g_mps2", "earth_rate_radps", "pulses_per_rev"):
        a, b = float(getattr(s, key)), float(getattr(t, key))
        if not math.isclose(a, b, rel_tol=GEOMETRY_RTOL, abs_tol=0.0):
            diffs.append(f"{key} = {a:g} in the session but {b:g} in the twin")
    if diffs:
        raise GapInputError(
            "the session comes from another station geometry: "
            + "; ".join(diffs)
            + ". Compare it with a twin configured for that station (--twin)."
        )
