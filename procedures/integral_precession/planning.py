"""Planning a seed-000 session before anything moves (seed 000 5.1.2-5.1.4).

The information matrix of the coefficients (kz, kzz, ky, k3) for a design of
positions and frequencies, its determinant det(Q) and the relative
sensitivity RES(n) as the number of equal-angle positions grows (eq. 23),
the measurement uncertainty of one window from counting and timing (eq. 24),
and the coefficient uncertainties that the design can reach (eq. 22).

Q = L^T L of the joint fit that identification uses (one static level per
position profiled out), averaged over the window phases t1, t2, which nobody
can plan: the kz column lives only on the window edges (<s> = (cos w t1 -
cos w t2)/(w Tm)), so a design evaluated at one phase could be singular by
accident. As the seed does, the output uncertainty is taken as constant
(that of a window of the planned length, eq. 24) for Q and eq. 22; positions
near 90 and 270 deg then show their true worth (no excitation of kzz and k3)
rather than the weight of their hours-long windows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station import constants
from station.session import StationInfo
from station.twin.plan import multiposition_plan
from station.twin.regressors import COEFFICIENTS, integral_regressors
from station.twin.window_means import window_means

PHASE_DRAWS = 64


def window_rate_sigma_radps(
    preset_pulses: np.ndarray | float,
    Tm_s: np.ndarray | float,
    sigma_p_pulses: float,
    sigma_T_s: float,
    pulses_per_rev: int,
) -> np.ndarray:
    """sigma of wbar = 2 pi P / (16384 Tm) from counting and timing (seed 000 eq. 24)."""
    P, Tm = np.asarray(preset_pulses, dtype=float), np.asarray(Tm_s, dtype=float)
    scale = 2 * math.pi / (pulses_per_rev * Tm)
    return scale * np.hypot(sigma_p_pulses, P * sigma_T_s / Tm)


@dataclass(frozen=True)
class DesignQuality:
    positions_deg: list[float]
    freqs_hz: list[float]
    Q: np.ndarray  # expected L^T L of (kz, kzz, ky, k3), static levels profiled out
    sigma_rate_radps: float  # eq. 24 for a window of the planned length
    sigma_k: np.ndarray  # eq. 22
    window_s: np.ndarray  # nominal Tm per point, the positions' test time

    @property
    def det_Q(self) -> float:
        return float(np.linalg.det(self.Q))


def design_quality(
    positions_deg: list[float],
    freqs_hz: list[float],
    station: StationInfo,
    *,
    window_s: float = 560.0,
    k0_radps: float = constants.K0_RADPS,
    kz_radps_per_g: float = constants.KZ_RADPS_PER_G,
    sigma_p_pulses: float = 1.0,
    sigma_T_s: float = 1e-6,
    seed: int = 0,
) -> DesignQuality:
    """Expected information and coefficient uncertainties of a multiposition design (eqs. 22, 24)."""
    plan = multiposition_plan(positions_deg, freqs_hz, window_s)
    pos = np.array([p.position_deg for p in plan])
    f = np.array([p.freq_hz for p in plan])
    P = np.array([p.preset_pulses for p in plan], dtype=float)
    theta = np.radians(pos)
    rate = np.abs(k0_radps + kz_radps_per_g * np.cos(theta))
    Tm = 2 * math.pi * P / (station.pulses_per_rev * rate)
    p_typ = window_s * kz_radps_per_g * station.pulses_per_rev / (2 * math.pi)
    sigma = float(window_rate_sigma_radps(p_typ, window_s, sigma_p_pulses, sigma_T_s, station.pulses_per_rev))
    _, index = np.unique(np.round(pos, 9), return_inverse=True)
    static_cols = np.eye(index.max() + 1)[index]
    vib = f > 0
    w = 2 * math.pi * f[vib]
    a = station.amplitude_ratio(f[vib])
    rng = np.random.default_rng(seed)
    info = np.zeros((static_cols.shape[1] + len(COEFFICIENTS),) * 2)
    for _ in range(PHASE_DRAWS):
        t1 = rng.uniform(0, 1 / f[vib])
        t2 = rng.uniform(0, 1 / f[vib])
        L = np.zeros((len(plan), len(COEFFICIENTS)))
        L[vib] = integral_regressors(theta[vib], a, *window_means(w, Tm[vib], t1, t2))
        X = np.hstack([static_cols, L])
        info += X.T @ X
    info /= PHASE_DRAWS
    n_static = static_cols.shape[1]
    A, B, C = info[:n_static, :n_static], info[:n_static, n_static:], info[n_static:, n_static:]
    Q = C - B.T @ np.linalg.solve(A, B)  # the static levels profiled out
    sigma_k = np.sqrt(np.diag(np.linalg.inv(Q))) * sigma
    return DesignQuality(list(map(float, positions_deg)), list(map(float, freqs_hz)), Q, sigma, sigma_k, Tm)


def relative_sensitivity(det_q: np.ndarray) -> np.ndarray:
    """RES(n) = (det Q(n) - det Q(n-1)) / det Q(n) with dN = 1 (seed 000 eq. 23); NaN for the first n."""
    d = np.asarray(det_q, dtype=float)
    out = np.full(d.shape, np.nan)
    out[1:] = (d[1:] - d[:-1]) / d[1:]
    return out
