"""Least squares with one static level per position, fitted jointly with the coefficients.

Vibration points of one position share its static point, so the differences
Y = wbar(i, j) - wbar(i, 0) are correlated and ordinary least squares on Y
understates sigma_k (physics.md). Fitting every measured rate directly,

    static:    wbar(i, 0) = c_i + e
    vibration: wbar(i, j) = c_i + L(i, j) K + e,

with independent errors, is the generalised least squares of Y with its true
covariance (the c_i are profiled out), so sigma_k = sqrt(diag((X^T X)^-1)) sigma
(seed 000 eq. 22) is honest. sigma = sqrt(e^T e / (n - p)) (eq. 21).

It lives in the core, not in procedures/ or the twin: it is the estimator of seed 000's identification
equations, a pure function of arrays that knows no procedure and simulates nothing, and both the
procedures (identification, budgets) and station.gap (which may import only the core and the twin) fit with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from station.errors import InputError


class FitError(InputError):
    """The design cannot identify the requested coefficients."""


@dataclass(frozen=True)
class JointFit:
    names: tuple[str, ...]
    values: np.ndarray
    cov: np.ndarray  # of the coefficients, sigma^2 scaled
    sigma_residual: float
    residuals: np.ndarray  # every measured rate, in the input order
    static_levels: np.ndarray
    dof: int
    # the coefficient rows of the fit's linear map from the rates: values = estimator @ rates, so the values'
    # covariance under any rate variances v is estimator diag(v) estimator^T (station.noise_form)
    estimator: np.ndarray

    @property
    def sigmas(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))


def fit_joint(
    rates_radps: np.ndarray,
    position_index: np.ndarray,
    regressors: np.ndarray,
    names: tuple[str, ...],
    weights: np.ndarray | None = None,
) -> JointFit:
    """Fit c_i (one per position index) and K; static rows have all-zero regressors."""
    rates = np.asarray(rates_radps, dtype=float)
    pos = np.asarray(position_index, dtype=np.int64)
    n_pos = int(pos.max()) + 1
    L = np.asarray(regressors, dtype=float)
    X = np.hstack([np.eye(n_pos)[pos], L])
    n, p = X.shape
    if n <= p:
        raise FitError(f"{n} points cannot fit {p} parameters ({n_pos} static levels + {', '.join(names)})")
    w = np.ones(n) if weights is None else np.sqrt(np.asarray(weights, dtype=float))
    Xw, yw = X * w[:, None], rates * w
    scale = np.linalg.norm(Xw, axis=0)
    if np.any(scale == 0):
        missing = [(f"static level {i}" if i < n_pos else names[i - n_pos]) for i in np.flatnonzero(scale == 0)]
        raise FitError(f"no point excites {', '.join(missing)}")
    Q, R = scipy.linalg.qr(Xw / scale, mode="economic")
    cond = np.linalg.cond(R)
    if not np.isfinite(cond) or cond > 1e13:
        raise FitError(f"the design is singular (condition number {cond:.3g}): the coefficients are not separable")
    beta_scaled = scipy.linalg.solve_triangular(R, Q.T @ yw)
    beta = beta_scaled / scale
    resid = rates - X @ beta
    dof = n - p
    sigma = math.sqrt(float(np.sum((resid * w) ** 2)) / dof)
    Rinv = scipy.linalg.solve_triangular(R, np.eye(p))
    cov_all = (Rinv @ Rinv.T) / np.outer(scale, scale) * sigma**2
    estimator = (Rinv[n_pos:] @ Q.T) * w[None, :] / scale[n_pos:, None]
    return JointFit(
        names=names,
        values=beta[n_pos:],
        cov=cov_all[n_pos:, n_pos:],
        sigma_residual=sigma,
        residuals=resid,
        static_levels=beta[:n_pos],
        dof=dof,
        estimator=estimator,
    )


def reliability(residuals: np.ndarray, sigma: float) -> tuple[float, float]:
    """mu = max|e| / sigma and mu_c = 1.25 + ln sqrt(N / 3) (seed 000 eq. 28)."""
    n = residuals.size
    mu = float(np.max(np.abs(residuals)) / sigma) if sigma > 0 else math.inf
    return mu, 1.25 + math.log(math.sqrt(n / 3.0))
