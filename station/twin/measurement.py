"""Measurement-point simulator: what the counter/timer and read head record for one point.

A point is one counter window: it opens on an output-pulse edge at a random
crank phase gamma0, closes on the P-th pulse edge (first passage, physics.md),
and the counter/timer time-stamps both edges and every reference crossing in
ticks of its timebase (50 ns, with a random timebase phase), after Gaussian
timing jitter. The read head's reference crossing is psi = reference_phase
mod 2 pi (0 by physics.md; pi reproduces seed 000's convention), stamped
late by the effects' reference latency (station.twin.effects.terms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.session import PointRecord, RawStreams
from station.twin.config import TwinConfig
from station.twin.effects import terms
from station.twin.plan import PointSpec
from station.twin.precession import PrecessionWindow, periodic_rate


@dataclass(frozen=True)
class SimulatedPoint:
    record: PointRecord
    window: PrecessionWindow
    true_Tm_s: float
    raw: RawStreams | None = None


class _Stamper:
    """Counter/timer time stamps: jitter, then ticks of the timebase, relative to the opening edge."""

    def __init__(self, cfg: TwinConfig, start_s: float, rng: np.random.Generator) -> None:
        self.tick_s = cfg.noise.timer_tick_s
        self.jitter_s = cfg.noise.timing_jitter_s
        self.rng = rng
        self.start_s = start_s
        self.phase_s = rng.uniform(0.0, self.tick_s) if self.tick_s > 0 else 0.0
        self._open_ticks = self._ticks(np.array([start_s + self._jitter(1)[0]]))[0] if self.tick_s > 0 else None
        self._open_jitter = 0.0 if self.tick_s > 0 else self._jitter(1)[0]

    def _jitter(self, n: int) -> np.ndarray:
        return self.rng.normal(0.0, self.jitter_s, n) if self.jitter_s > 0 else np.zeros(n)

    def _ticks(self, t_abs_s: np.ndarray) -> np.ndarray:
        return np.floor((t_abs_s - self.phase_s) / self.tick_s).astype(np.int64)

    def stamp(self, t_rel_s: np.ndarray) -> np.ndarray:
        """Recorded times (s from the recorded opening) of true times t_rel after the opening edge."""
        t_rel_s = np.asarray(t_rel_s, dtype=float)
        jittered = t_rel_s + self._jitter(t_rel_s.size)
        if self.tick_s <= 0:
            return jittered - self._open_jitter
        return (self._ticks(self.start_s + jittered) - self._open_ticks) * self.tick_s


def simulate_point(
    spec: PointSpec,
    cfg: TwinConfig,
    rng: np.random.Generator,
    *,
    start_s: float = 0.0,
    point_id: str = "p0",
    sequence: int = 0,
    reference_phase_rad: float = 0.0,
    raw: bool = False,
) -> SimulatedPoint:
    """Simulate one point: pulses, Tm, t1, t2, Np (and the raw streams on request)."""
    theta = math.radians(spec.position_deg)
    vib = spec.freq_hz != 0.0
    f_true = spec.freq_hz * (1.0 + terms.frequency_offset(cfg.effects)) if vib else 0.0
    w_true = 2.0 * math.pi * f_true
    rate = periodic_rate(theta, f_true, cfg)
    target = spec.preset_pulses * cfg.station.pulse_angle_rad
    offset = 0.0
    if cfg.noise.rate_noise_radps > 0:
        tm_est = target / max(abs(rate.c0_radps), 1e-12)
        sd = cfg.noise.rate_noise_radps * math.sqrt(cfg.noise.rate_noise_ref_s / tm_est)
        offset = rng.normal(0.0, sd)
    gamma0 = rng.uniform(0.0, 2.0 * math.pi) if vib else 0.0
    window = PrecessionWindow(rate, w_true, gamma0, offset, terms.bias_slope_radps2(cfg.effects), start_s)
    tm_true = window.first_passage_s(target)
    sign = 1 if window.mean_rate_radps >= 0 else -1
    stamper = _Stamper(cfg, start_s, rng)
    tm = float(stamper.stamp(np.array([tm_true]))[0])
    t1 = t2 = None
    n_periods = None
    crossings = None
    if vib:
        crossings = _reference_crossings(window, tm_true, reference_phase_rad, cfg, stamper)
        after_open = np.flatnonzero(crossings > 0.0)
        i1 = int(after_open[0])
        i_close = int(np.flatnonzero(crossings >= tm)[0])
        t1 = float(crossings[i1])
        t2 = float(crossings[i_close] - tm)
        n_periods = i_close - i1
    record = PointRecord(
        point_id=point_id,
        sequence=sequence,
        start_s=start_s,
        position_deg=spec.position_deg,
        freq_hz=spec.freq_hz,
        kind=spec.kind,
        pulses=sign * spec.preset_pulses,
        Tm_s=tm,
        t1_s=t1,
        t2_s=t2,
        Np=n_periods,
    )
    streams = None
    if raw:
        from station.twin.raw import raw_streams

        t_end = tm_true + (t2 if t2 is not None else 0.0)
        streams = raw_streams(window, cfg, spec, t_end, start_s, rng, crossings)
    return SimulatedPoint(record, window, tm_true, streams)


def _reference_crossings(
    window: PrecessionWindow,
    tm_true_s: float,
    reference_phase_rad: float,
    cfg: TwinConfig,
    stamper: _Stamper,
) -> np.ndarray:
    """Recorded times of every reference crossing from one period before the opening to one after Tm."""
    w = window.w_radps
    latency = terms.reference_latency_s(cfg.effects)
    # psi(t) = w t + gamma0 = reference_phase + 2 pi m  ->  t_m = (reference_phase + 2 pi m - gamma0) / w
    m0 = math.floor((window.gamma0_rad - reference_phase_rad) / (2 * math.pi)) - 1
    m1 = math.ceil((w * (tm_true_s + abs(latency)) + window.gamma0_rad - reference_phase_rad) / (2 * math.pi)) + 2
    m = np.arange(m0, m1 + 1, dtype=float)
    t_true = (reference_phase_rad + 2.0 * math.pi * m - window.gamma0_rad) / w + latency
    return stamper.stamp(t_true)
