"""Coefficient identification from a recorded session (physics.md; seed 000 eqs. 19-22, 28-29, 35).

`integral`: the integral precession model with exact window means from t1,
t2 and Tm. `baseline`: the classical integer periodic vibration model (eq.
35), which drops the window-edge terms and so cannot see kz.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from methods.common.least_squares import FitError, JointFit, fit_joint, reliability
from models.regressors import (
    BASELINE_COEFFICIENTS,
    COEFFICIENTS,
    baseline_regressors,
    integral_regressors,
)
from models.window_means import window_means
from station.session import Session

Method = Literal["integral", "baseline"]
METHODS: tuple[str, ...] = ("integral", "baseline")


@dataclass(frozen=True)
class Compensation:
    """Measured table errors to compensate (seed 000 6.1): Zs1(w) in metres, axs1 in rad."""

    zs1_m: Callable[[float], float] | None = None
    axs1_rad: float = 0.0


@dataclass
class Identification:
    method: str
    names: tuple[str, ...]
    values: np.ndarray
    sigmas: np.ndarray
    sigma_residual: float
    mu: float
    mu_c: float
    n_points: int
    dof: int
    point_ids: list[str]
    residuals: np.ndarray  # of every measured rate (joint fit)
    vib_ids: list[str] = field(default_factory=list)
    Y: np.ndarray = field(default_factory=lambda: np.zeros(0))
    Y_residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    proportional_residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def coefficient(self, name: str) -> tuple[float, float]:
        i = self.names.index(name)
        return float(self.values[i]), float(self.sigmas[i])

    def to_json(self) -> dict:
        coefs = {}
        for name in COEFFICIENTS:
            if name in self.names:
                v, s = self.coefficient(name)
                coefs[name] = {"value": v, "sigma": s}
            else:
                coefs[name] = {"value": None, "sigma": None, "note": f"not identifiable by the {self.method} model"}
        return {
            "method": self.method,
            "coefficients": coefs,
            "sigma_residual": self.sigma_residual,
            "mu": self.mu,
            "mu_c": self.mu_c,
            "reliable": self.mu < self.mu_c,
            "n_points": self.n_points,
            "dof": self.dof,
            "units": {
                "kz": "rad/s/g",
                "kzz": "rad/s/g^2",
                "ky": "rad/s/g^2",
                "k3": "rad/s/g^3",
                "sigma_residual": "rad/s",
            },
        }


def _position_indices(positions_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    keys = np.round(positions_deg, 9)
    uniq, index = np.unique(keys, return_inverse=True)
    return uniq, index


def design(session: Session, method: Method = "integral", compensation: Compensation | None = None):
    """Rates, position index, regressor rows (zeros for static points) and coefficient names."""
    if method not in METHODS:
        raise ValueError(f"method {method!r} is not one of {', '.join(METHODS)}")
    comp = compensation or Compensation()
    pts = session.points
    if not pts:
        raise FitError("the session has no points")
    rates = session.rates_radps()
    pos_deg = np.array([p.position_deg for p in pts])
    _uniq, index = _position_indices(pos_deg)
    vib = np.array([p.kind == "vibration" for p in pts])
    has_static = {int(i) for i, v in zip(index, vib, strict=True) if not v}
    for p, i, v in zip(pts, index, vib, strict=True):
        if v and int(i) not in has_static:
            raise FitError(
                f"vibration point {p.point_id!r} at position {p.position_deg} deg has no static point "
                "at that position to reference it"
            )
    names = COEFFICIENTS if method == "integral" else BASELINE_COEFFICIENTS
    L = np.zeros((len(pts), len(names)))
    if vib.any():
        vp = [p for p in pts if p.kind == "vibration"]
        f = np.array([p.freq_hz for p in vp])
        w = 2 * math.pi * f
        a = session.station.amplitude_ratio(f)
        if comp.zs1_m is not None:
            a = a * (1.0 + np.array([comp.zs1_m(wi) for wi in w]) / session.station.A0_m)
        theta = np.radians([p.position_deg for p in vp])
        if method == "integral":
            Tm = np.array([p.Tm_s for p in vp])
            t1 = np.array([p.t1_s for p in vp], dtype=float)
            t2 = np.array([p.t2_s for p in vp], dtype=float)
            s1, s2, s3 = window_means(w, Tm, t1, t2)
            L[vib] = integral_regressors(theta, a, s1, s2, s3, comp.axs1_rad)
        else:
            L[vib] = baseline_regressors(theta, a)
    return rates, index, L, names, vib


def identify(session: Session, method: Method = "integral", compensation: Compensation | None = None) -> Identification:
    """Fit the session and evaluate it (sigma, sigma_k, mu vs mu_c, proportional residuals)."""
    rates, index, L, names, vib = design(session, method, compensation)
    if not vib.any():
        raise FitError("the session has no vibration points: the nonlinear coefficients need vibration")
    fit: JointFit = fit_joint(rates, index, L, names)
    mu, mu_c = reliability(fit.residuals, fit.sigma_residual)
    pts = session.points
    Y = rates[vib] - fit.static_levels[index[vib]]
    y_res = Y - L[vib] @ fit.values
    theta = np.radians([p.position_deg for p, v in zip(pts, vib, strict=True) if v])
    a = session.station.amplitude_ratio([p.freq_hz for p, v in zip(pts, vib, strict=True) if v])
    with np.errstate(divide="ignore"):
        prop = y_res / (a * np.abs(np.cos(theta)))
    return Identification(
        method=method,
        names=names,
        values=fit.values,
        sigmas=fit.sigmas,
        sigma_residual=fit.sigma_residual,
        mu=mu,
        mu_c=mu_c,
        n_points=len(pts),
        dof=fit.dof,
        point_ids=[p.point_id for p in pts],
        residuals=fit.residuals,
        vib_ids=[p.point_id for p, v in zip(pts, vib, strict=True) if v],
        Y=Y,
        Y_residuals=y_res,
        proportional_residuals=prop,
        cov=fit.cov,
    )
