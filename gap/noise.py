"""Honest noise: rate noise from repeats or the residual dof, scaled by window length and timing.

White rate noise averages over the counter window, so the window-mean rate of
point i has variance sigma0^2 T_ref / Tm_i (the twin's NoiseModel form:
rate_noise_radps at rate_noise_ref_s); the two time stamps that bound Tm add
(wbar_i sigma_tau / Tm_i)^2, since wbar = 2 pi P / (16384 Tm). sigma0 is
estimated from the data, never taken from a nominal constant:
- from repeats (points with the same position, frequency and kind): the
  spread of their residuals about the group mean (pure error, independent of
  any model gap that repeats share), when it has PURE_ERROR_MIN_DOF dof;
- otherwise from the residuals of the final model, sigma0^2 = sum w_i e_i^2 / dof
  (seed 000 eq. 21 with these weights), after the generic structure that the
  structure tests found significant (gap.localise) is taken out too,
  so that a gap the library does not explain is not mistaken for noise.
The period identity tau = t2 - t1 + Tm - Np T has the noise of two time
stamps: sigma_tau is estimated from its scatter once a single frequency error
is allowed for, never below the counter's quantisation, tick sqrt(2 / 12).
The twin's own rate_noise_radps is only compared with (a chi-square test),
as one more way the station can differ from its twin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from gap.design import PointDesign
from models.config import TwinConfig

PURE_ERROR_MIN_DOF = 5


def timing_rate_sd_radps(design: PointDesign, sigma_tau_s: float) -> np.ndarray:
    """Rate error from the two stamps that bound Tm: |wbar| sigma_tau / Tm."""
    return np.abs(design.rate_radps) * sigma_tau_s / design.Tm_s


def rate_weights(
    design: PointDesign, twin: TwinConfig, sigma_tau_s: float = 0.0, sigma0_radps: float = math.inf
) -> np.ndarray:
    """w_i = sigma0^2 / var(wbar_i) = 1 / (T_ref / Tm_i + (timing sd_i / sigma0)^2)."""
    var = twin.noise.rate_noise_ref_s / design.Tm_s
    if sigma_tau_s > 0 and math.isfinite(sigma0_radps):
        var = var + (timing_rate_sd_radps(design, sigma_tau_s) / sigma0_radps) ** 2
    return 1.0 / var


@dataclass(frozen=True)
class TimingNoise:
    sigma_tau_s: float
    dof: int
    floor_s: float
    eps_f_hat: float  # the single frequency error that the period identities imply


def timing_noise(design: PointDesign, twin: TwinConfig) -> TimingNoise:
    """sigma of the period identity after a single frequency error is fitted to it."""
    floor = twin.noise.timer_tick_s * math.sqrt(2.0 / 12.0)
    v = design.vib
    span = design.Np[v] / design.freq_hz[v]  # Np T_cmd
    tau = design.tau_s[v]
    # tau = Np T_cmd (1 / (1 + eps) - 1) = span * x, linear in x.
    x = float(span @ tau / (span @ span)) if span.size else 0.0
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
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(zip(np.round(design.position_deg, 6), np.round(design.freq_hz, 6), strict=True)):
        groups.setdefault(key, []).append(i)
    ss, dof, n_groups = 0.0, 0, 0
    for idx in groups.values():
        if len(idx) < 2:
            continue
        r, w = residuals_radps[idx], weights[idx]
        mean = float(np.sum(w * r) / np.sum(w))
        ss += float(np.sum(w * (r - mean) ** 2))
        dof += len(idx) - 1
        n_groups += 1
    return PureError(math.sqrt(ss / dof), dof, n_groups) if dof else None


@dataclass(frozen=True)
class HonestNoise:
    sigma0_radps: float
    dof: int
    source: str


def honest_noise(
    pe: PureError | None,
    r_white: np.ndarray,
    n_rate: int,
    dof: int,
    sigma_white_radps: float,
    structure: list[np.ndarray],
) -> HonestNoise:
    """sigma0 at T_ref: pure error, else the final model's rate residual (r_white: whitened by sigma_white,
    rate rows first) with the columns of the significant structure blocks (orthonormal, off the model) taken out."""
    if pe is not None and pe.dof >= PURE_ERROR_MIN_DOF:
        return HonestNoise(pe.sigma0_radps, pe.dof, "pure error of repeats")
    rss, source = float(r_white[:n_rate] @ r_white[:n_rate]), "residuals of the final model"
    if structure:
        U, s, _ = np.linalg.svd(np.hstack(structure), full_matrices=False)
        U = U[:, s > 1e-8 * s.max()]
        rss -= float(np.sum((U.T @ r_white) ** 2))
        dof -= U.shape[1]
        source += " after the significant structure (see where)"
    return HonestNoise(sigma_white_radps * math.sqrt(max(rss, 0.0) / dof), dof, source)


def excess_scatter_pvalue(sigma_hat: float, dof: int, sigma_ref: float) -> float:
    """P(chi2_dof >= dof sigma_hat^2 / sigma_ref^2): small when the scatter exceeds the reference."""
    if sigma_ref <= 0 or dof <= 0:
        return float("nan")
    return float(stats.chi2.sf(dof * (sigma_hat / sigma_ref) ** 2, dof))


def lack_of_fit_pvalue(rss_radps2: float, dof: int, pe: PureError) -> float:
    """F-test of the model's residual scatter against the pure error of repeats."""
    if dof <= pe.dof:
        return float("nan")
    lof = max(rss_radps2 - pe.sigma0_radps**2 * pe.dof, 0.0) / (dof - pe.dof)
    return float(stats.f.sf(lof / max(pe.sigma0_radps**2, 1e-300), dof - pe.dof, pe.dof))
