"""Simulate a whole session from a plan: points in order, session time advancing, seeded."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from station.session import Session, StationInfo
from station.twin.config import TwinConfig
from station.twin.measurement import SimulatedPoint, simulate_point
from station.twin.plan import PointSpec, point_id

SETUP_TIME_S = 60.0  # index move, ramp and settle between points (nominal)


def station_info(cfg: TwinConfig) -> StationInfo:
    s = cfg.station
    return StationInfo(s.A0_m, s.latitude_deg, s.g_mps2, s.earth_rate_radps, s.pulses_per_rev)


def simulate_points(
    plan: Sequence[PointSpec],
    cfg: TwinConfig,
    seed: int = 0,
    *,
    raw: bool = False,
    reference_phase_rad: float = 0.0,
    setup_time_s: float = SETUP_TIME_S,
):
    """Yield SimulatedPoint for each planned point in order (a generator, so a caller can store as it goes)."""
    rng = np.random.default_rng(seed)
    t_s = 0.0
    for i, spec in enumerate(plan):
        t_s += setup_time_s
        sp: SimulatedPoint = simulate_point(
            spec,
            cfg,
            rng,
            start_s=t_s,
            point_id=point_id(i, spec),
            sequence=i,
            reference_phase_rad=reference_phase_rad,
            raw=raw,
        )
        t_s += sp.true_Tm_s + (sp.record.t2_s or 0.0)
        yield sp


def simulate_session(
    plan: Sequence[PointSpec], cfg: TwinConfig, seed: int = 0, *, raw: bool = False, notes: str = ""
) -> Session:
    points, raws = [], {}
    for sp in simulate_points(plan, cfg, seed, raw=raw):
        points.append(sp.record)
        if sp.raw is not None:
            raws[sp.record.point_id] = sp.raw
    return Session(station_info(cfg), points, notes=notes, raw=raws)
