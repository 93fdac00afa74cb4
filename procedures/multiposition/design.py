"""Designing the position sequence (seed 003 5.1-5.2): uncertainty factors, ES(n) and test time.

Q = X^T X of the static model at the positions (seed 003 eq. 47), d_ii = diag(Q^-1)
(Fig. 4: sigma_k = sqrt(d_ii) sigma, eq. 49). ES(n) asks what one more position is
worth per position: the relative change of det(Q(n) / n), the design's D-efficiency per
position, in the form of seed 000's RES(n) (eq. 23); seed 003's own ES equation is lost
in the OCR. The test time at a position is the preset precession angle over the rate,
t = 2 pi P / (16384 |wbar|) (physics.md), so positions near 90 and 270 deg, where
wbar is k0 and the earth rate alone, cost hours (Figs. 6-7).
"""

from __future__ import annotations

import math

import numpy as np

from procedures.integral_precession.alignment import earth_rate_along_ia
from procedures.integral_precession.planning import relative_sensitivity
from procedures.multiposition.sequences import sequence_deg
from procedures.multiposition.static_model import regressors
from station.session import StationInfo


def information_matrix(positions_deg: list[float], terms: tuple[str, ...]) -> np.ndarray:
    """Q = X^T X (seed 003 eq. 47) for unit output uncertainty."""
    X = regressors(np.cos(np.radians(positions_deg)), terms)
    return X.T @ X


def uncertainty_factors(positions_deg: list[float], terms: tuple[str, ...]) -> np.ndarray:
    """d_ii = diag(Q^-1): sigma_k = sqrt(d_ii) sigma (seed 003 eq. 49, Fig. 4); inf where Q is singular."""
    Q = information_matrix(positions_deg, terms)
    if np.linalg.matrix_rank(Q) < len(terms):
        return np.full(len(terms), math.inf)
    return np.diag(np.linalg.inv(Q))


def efficiency_sensitivity(scheme: str, ns: np.ndarray, terms: tuple[str, ...]) -> np.ndarray:
    """ES(n) = (det(Q(n)/n) - det(Q(n-1)/(n-1))) / det(Q(n)/n); NaN where either design is singular."""
    ns = np.asarray(ns, dtype=int)
    det = np.array([np.linalg.det(information_matrix(sequence_deg(scheme, int(n)), terms) / n) for n in ns])
    det[det < 1e-12 * np.max(det)] = math.nan
    out = relative_sensitivity(det)
    out[np.concatenate([[True], np.diff(ns) != 1])] = math.nan  # defined for consecutive n only
    return out


def static_rate_estimate_radps(theta_a_rad: np.ndarray, k0_radps: float, kz_radps_per_g: float,
                               station: StationInfo) -> np.ndarray:  # fmt: skip
    """wbar ~ k0 + kz cos theta - w_ie sin(lam - theta), the planning estimate of the output (seed 003 5.2)."""
    theta = np.asarray(theta_a_rad, dtype=float)
    return k0_radps + kz_radps_per_g * np.cos(theta) - earth_rate_along_ia(theta, station)


def window_s(precession_rad: float, rate_radps: np.ndarray) -> np.ndarray:
    """The test time of a window of a preset precession angle: angle / |wbar| (physics.md)."""
    return precession_rad / np.abs(np.asarray(rate_radps, dtype=float))


def total_test_time_s(scheme: str, n: int, precession_rad: float, k0_radps: float, kz_radps_per_g: float,
                      station: StationInfo) -> float:  # fmt: skip
    """t_total of an n-position sequence: the sum of its windows (seed 003 Figs. 6-7; moves not included)."""
    rate = static_rate_estimate_radps(np.radians(sequence_deg(scheme, n)), k0_radps, kz_radps_per_g, station)
    return float(np.sum(window_s(precession_rad, rate)))
