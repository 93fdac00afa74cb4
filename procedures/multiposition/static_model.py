"""The static rate model on the indexing head and its least squares (physics.md static; seed 003 eqs. 14, 43-49).

    wbar = k0 + kz c + kzz c^2 + koq c|c| + ky (1 - c^2) + k3 c^3 - w_ie sin(lam - theta_a),  c = cos theta_a

From static positions alone 1, c^2 and 1 - c^2 are linearly dependent: only k0 + ky and
kzz - ky are identifiable (vibration separates them, seed 000). The fit therefore names
what it identifies: "k0+ky", "kz", "kzz-ky", "koq", and "k3" in physics.md's full model;
seed 003's calibration model (eq. 14) has no cubic term.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from procedures.integral_precession.alignment import earth_rate_along_ia
from procedures.multiposition.lsq import Fit, solve
from station.session import StationInfo
from station.twin.config import InstrumentCoefficients

MODELS: Mapping[str, tuple[str, ...]] = {
    "seed003": ("k0+ky", "kz", "kzz-ky", "koq"),
    "physics": ("k0+ky", "kz", "kzz-ky", "koq", "k3"),
}
_COLUMNS = {
    "k0+ky": (lambda c: np.ones_like(c), lambda c: np.zeros_like(c)),
    "kz": (lambda c: c, lambda c: np.ones_like(c)),
    "kzz-ky": (lambda c: c * c, lambda c: 2 * c),
    "koq": (lambda c: c * np.abs(c), lambda c: 2 * np.abs(c)),
    "k3": (lambda c: c**3, lambda c: 3 * c * c),
}


def regressors(c: np.ndarray, terms: tuple[str, ...]) -> np.ndarray:
    """Columns of the identifiable terms at input accelerations c (g)."""
    c = np.asarray(c, dtype=float)
    return np.column_stack([_COLUMNS[t][0](c) for t in terms])


def regressor_slopes(c: np.ndarray, terms: tuple[str, ...]) -> np.ndarray:
    """d/dc of each column (the joint fit's Jacobian through the angle)."""
    c = np.asarray(c, dtype=float)
    return np.column_stack([_COLUMNS[t][1](c) for t in terms])


def static_rate_radps(theta_a_rad: np.ndarray, values: np.ndarray, terms: tuple[str, ...], station: StationInfo):
    """wbar at instrument angles theta_a, earth rate included."""
    theta = np.asarray(theta_a_rad, dtype=float)
    return regressors(np.cos(theta), terms) @ values - earth_rate_along_ia(theta, station)


def rate_slope_radps(theta_a_rad: np.ndarray, values: np.ndarray, terms: tuple[str, ...], station: StationInfo):
    """d(wbar)/d(theta_a): the polynomial through c = cos theta_a, and the earth rate -w_ie sin(lam - theta_a)."""
    theta = np.asarray(theta_a_rad, dtype=float)
    slope = regressor_slopes(np.cos(theta), terms) @ values
    lam = np.radians(station.latitude_deg)
    return -np.sin(theta) * slope + station.earth_rate_radps * np.cos(lam - theta)


def with_angle_uncertainty(fit: Fit, theta_a_rad: np.ndarray, dtheta_dq: np.ndarray, cov_q: np.ndarray,
                           station: StationInfo) -> Fit:  # fmt: skip
    """The fit's covariance with that of angles computed from estimated parameters q added.

    K = pinv(X) y depends on q through the angles: dK/dq = -pinv(X) (dwbar/dtheta_a) dtheta_a/dq, and
    the data of q are independent of this fit's, so cov K = cov_LS + (dK/dq) cov_q (dK/dq)^T.
    """
    theta = np.asarray(theta_a_rad, dtype=float)
    X = regressors(np.cos(theta), fit.names)
    S = -np.linalg.pinv(X) @ (rate_slope_radps(theta, fit.values, fit.names, station)[:, None] * dtheta_dq)
    return replace(fit, cov=fit.cov + S @ cov_q @ S.T)


def fit_static(theta_a_rad: np.ndarray, rates_radps: np.ndarray, terms: tuple[str, ...], station: StationInfo) -> Fit:
    """Least squares of the static model at known instrument angles (seed 003 eqs. 43-49)."""
    theta = np.asarray(theta_a_rad, dtype=float)
    X = regressors(np.cos(theta), terms)
    y = np.asarray(rates_radps, dtype=float) + earth_rate_along_ia(theta, station)
    return solve(lambda k: X @ k - y, lambda k: X, np.zeros(len(terms)), terms)


def relative_fitting_accuracy_g(fit: Fit) -> np.ndarray:
    """The residuals as input-acceleration errors, e_i / kz in g (seed 003 Figs. 10-11)."""
    return fit.residuals / fit.value("kz")[0]


def true_static_terms(instrument: InstrumentCoefficients, koq: float = 0.0) -> dict[str, float]:
    """The identifiable combinations of a twin's coefficients."""
    k = instrument
    return {"k0+ky": k.k0 + k.ky, "kz": k.kz, "kzz-ky": k.kzz - k.ky, "koq": koq, "k3": k.k3}
