"""Honest noise: rate noise from the fit's residual dof and from repeats, scaled by window length.

White rate noise averages over the counter window, so the window-mean rate of
point i has standard deviation sigma_i = sigma0 sqrt(T_ref / Tm_i) (the
twin's NoiseModel: rate_noise_radps at rate_noise_ref_s). sigma0 is
estimated from the data, never taken from a nominal constant:
- from the residuals of a fit, sigma0^2 = sum (Tm_i / T_ref) e_i^2 / dof
  (seed 000 eq. 21 with the 1/Tm weights);
- from repeats (points with the same position, frequency and kind), the
  spread of their residuals about the group mean (pure error, independent
  of any model gap that repeats share).
Timing enters twice: the period identity tau = t2 - t1 + Tm - Np T has
the noise of two time stamps (sigma_tau, estimated from its scatter once a
single frequency error is allowed for, never below the counter's
quantisation tick / sqrt(6)); and a time-stamp error dt moves the measured
rate by wbar dt / Tm, which `timing_rate_sd_radps` bounds.
The twin's own rate_noise_radps is only compared with (a chi-square test),
as one more way the station can differ from its twin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from station.gap.design import PointDesign
from station.twin.config import TwinConfig


def rate_weights(design: PointDesign, twin: TwinConfig) -> np.ndarray:
    """w_i = Tm_i / T_ref, so that var(wbar_i) = sigma0^2 / w_i (white rate noise)."""
    return design.Tm_s / twin.noise.rate_noise_ref_s


def timing_stamp_sd_s(twin: TwinConfig) -> float:
    """Standard deviation of one recorded time stamp: jitter and the tick's quantisation."""
    tick = twin.noise.timer_tick_s
    return math.sqrt(twin.noise.timing_jitter_s**2 + tick * tick / 12.0)


def timing_rate_sd_radps(design: PointDesign, twin: TwinConfig) -> np.ndarray:
    """Rate error from the two stamps that bound Tm: |wbar| sqrt(2) sd_stamp / Tm."""
    return np.abs(design.rate_radps) * math.sqrt(2.0) * timing_stamp_sd_s(twin) / design.Tm_s


@dataclass(frozen=True)
class TimingNoise:
    sigma_tau_s: float
    dof: int
    floor_s: float
    eps_f_hat: float  # the single frequency error that the period identities imply


def timing_noise(design: PointDesign, twin: TwinConfig) -> TimingNoise:
    """sigma of the period identity after a single frequency error is fitted to it."""
    floor = math.sqrt(2.0) * twin.noise.timer_tick_s / math.sqrt(12.0)
    v = design.vib
    if not v.any():
        return TimingNoise(floor, 0, floor, 0.0)
    span = design.Np[v] / design.freq_hz[v]  # Np T_cmd
    tau = design.tau_s[v]
    # tau = Np T_cmd (1 / (1 + eps) - 1) = span * x, linear in x.
    x = float(span @ tau / (span @ span))
    eps = 1.0 / (1.0 + x) - 1.0
    dof = int(v.sum()) - 1
    if dof < 1:
        return TimingNoise(floor, 0, floor, eps)
    sd = math.sqrt(float(np.sum((tau - span * x) ** 2)) / dof)
    return TimingNoise(max(sd, floor), dof, floor, eps)


@dataclass(frozen=True)
class PureError:
    sigma0_radps: float
    dof: int
    groups: int


def pure_error(design: PointDesign, residuals_radps: np.ndarray, weights: np.ndarray) -> PureError | None:
    """sigma0 from repeats: weighted spread of residuals within (position, frequency, kind) groups."""
    keys = [
        (round(float(p), 6), round(float(f), 6), bool(v))
        for p, f, v in zip(design.position_deg, design.freq_hz, design.vib, strict=True)
    ]
    groups: dict[tuple, list[int]] = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)
    ss, dof, n_groups = 0.0, 0, 0
    for idx in groups.values():
        if len(idx) < 2:
            continue
        r, w = residuals_radps[idx], weights[idx]
        mean = float(np.sum(w * r) / np.sum(w))
        ss += float(np.sum(w * (r - mean) ** 2))
        dof += len(idx) - 1
        n_groups += 1
    if dof == 0:
        return None
    return PureError(math.sqrt(ss / dof), dof, n_groups)


def excess_scatter_pvalue(sigma_hat: float, dof: int, sigma_ref: float) -> float:
    """P(chi2_dof >= dof sigma_hat^2 / sigma_ref^2): small when the scatter exceeds the reference."""
    if sigma_ref <= 0 or dof <= 0:
        return float("nan")
    return float(stats.chi2.sf(dof * (sigma_hat / sigma_ref) ** 2, dof))
