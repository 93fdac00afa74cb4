"""Self-alignment of the PIGA on the indexing head from static windows (seed 000 eqs. 25-27).

Eq. 25: wbar + w_ie sin(lam - theta) = k0 + kz cos(theta + dtheta_h).

Two positions, 0 and 180 deg, as the seed does (eq. 26):
    cos(dtheta_h) = (wbar_0 - wbar_180 + 2 w_ie sin lam) / (2 kz)
which gives |dtheta_h| only, and poorly: near zero, cos is flat, so a 1e-6
relative error of kz or of the rates is an angle error of 1.4e-3 rad. Eq. 27
propagates that honestly (its derivative 1/sin(dtheta_h) grows without bound).

Three or more positions: eq. 25 is linear in (k0, kz cos dtheta_h, kz sin
dtheta_h) and least squares gives the signed angle and kz together, with
their covariance. A design symmetric about 0 deg (0, 60, 180, 300) keeps the
nonlinear terms, which eq. 25 leaves out, from biasing the sine component.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from procedures.common.uncertainty import coverage_factor, gum_fields
from station.session import StationInfo


@dataclass(frozen=True)
class Alignment:
    method: str
    dtheta_h_rad: float
    sigma_rad: float | None  # None: no residual degrees of freedom to estimate it
    kz_radps_per_g: float
    sigma_kz: float | None
    k0_radps: float
    residual_sigma_radps: float | None  # None: no residual degrees of freedom (eq. 26, or three positions)
    sigma_k0_radps: float | None = None  # None where the design gives no estimate of it
    dof: float = math.inf  # of every sigma: the fit's n - 3 (eq. 25), infinite for eq. 27's propagated inputs

    def quantity(self, value: float, sigma: float | None, unit: str) -> dict:
        """value, sigma, unit and, where sigma is finite, the GUM fields with k = Student's t at `dof`."""
        q: dict = {"value": value, "sigma": sigma, "unit": unit}
        if sigma is not None and math.isfinite(sigma) and self.dof > 0:
            q |= gum_fields(sigma, self.dof, coverage_factor(self.dof))
        return q

    def to_json(self) -> dict:
        """Quantities with value, sigma, unit and U = k u; a sigma the design cannot give is None with the reason."""
        k0 = self.quantity(self.k0_radps, self.sigma_k0_radps, "rad/s")
        if self.sigma_k0_radps is None:
            k0["note"] = "no residual degrees of freedom: sigma(k0) not estimable"
        return {
            "method": self.method,
            "dtheta_h": self.quantity(self.dtheta_h_rad, self.sigma_rad, "rad"),
            "kz": self.quantity(self.kz_radps_per_g, self.sigma_kz, "rad/s/g"),
            "k0": k0,
            "residual_sigma_radps": self.residual_sigma_radps,
            "dof": self.dof if math.isfinite(self.dof) else None,
        }


def earth_rate_along_ia(theta_rad: np.ndarray, station: StationInfo, latitude_rad: float | None = None) -> np.ndarray:
    """w_ie sin(lam - theta): the earth rate along IA (physics.md inputs)."""
    lam = station.latitude_rad if latitude_rad is None else latitude_rad
    return station.earth_rate_radps * np.sin(lam - np.asarray(theta_rad, dtype=float))


def two_position(
    rate_0_radps: float,
    rate_180_radps: float,
    station: StationInfo,
    *,
    kz_radps_per_g: float,
    sigma_rate_radps: float,
    sigma_latitude_rad: float,
    sigma_kz: float,
) -> Alignment:
    """|dtheta_h| by eq. 26 and its uncertainty by eq. 27."""
    lam = station.latitude_rad
    wie = station.earth_rate_radps
    c = (rate_0_radps - rate_180_radps + 2 * wie * math.sin(lam)) / (2 * kz_radps_per_g)
    angle = math.acos(min(c, 1.0))
    s = math.sin(angle)
    # d(angle)/dc = -1/sin(angle); dc/dwbar = 1/(2 kz); dc/dlam = wie cos(lam)/kz; dc/dkz = -c/kz
    d_dc = math.inf if s == 0 else 1.0 / s
    var_c = 2 * (sigma_rate_radps / (2 * kz_radps_per_g)) ** 2
    var_c += (wie * math.cos(lam) / kz_radps_per_g * sigma_latitude_rad) ** 2 + (c / kz_radps_per_g * sigma_kz) ** 2
    sigma = d_dc * math.sqrt(var_c)
    k0 = 0.5 * (rate_0_radps + rate_180_radps)  # the earth-rate terms cancel in the sum at 0 and 180 deg
    sigma_k0 = sigma_rate_radps / math.sqrt(2.0)  # the mean of two rates of sigma_rate each
    return Alignment("eq. 26 (0 and 180 deg)", angle, sigma, kz_radps_per_g, sigma_kz, k0, None, sigma_k0)


def multi_position(theta_rad: np.ndarray, rates_radps: np.ndarray, station: StationInfo) -> Alignment:
    """Signed dtheta_h and kz by least squares of eq. 25 over three or more static positions."""
    theta = np.asarray(theta_rad, dtype=float)
    y = np.asarray(rates_radps, dtype=float) + earth_rate_along_ia(theta, station)
    X = np.column_stack([np.ones_like(theta), np.cos(theta), -np.sin(theta)])
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    dof = len(y) - 3
    resid = y - X @ beta
    sigma_e = math.sqrt(float(resid @ resid) / dof) if dof > 0 else None
    cov = np.linalg.inv(X.T @ X) * (sigma_e**2 if sigma_e is not None else math.nan)
    k0, a, b = beta  # a = kz cos(d), b = kz sin(d)
    kz = math.hypot(a, b)
    angle = math.atan2(b, a)
    # gradients of (kz, angle) with respect to (a, b)
    J = np.array([[a / kz, b / kz], [-b / kz**2, a / kz**2]])
    cov_ka = J @ cov[1:, 1:] @ J.T

    def sd(var: float) -> float | None:
        return math.sqrt(var) if sigma_e is not None else None

    return Alignment(f"eq. 25 least squares ({len(y)} positions)", angle, sd(cov_ka[1, 1]), kz, sd(cov_ka[0, 0]),
                     float(k0), sigma_e, sd(cov[0, 0]), dof=float(dof))  # fmt: skip
