"""Least squares with their uncertainties, by scipy (seed 003 eqs. 44-49).

K = argmin |r(K)|^2; sigma = sqrt(r^T r / (n - p)) (eq. 48); sigma_k = sqrt(diag((J^T J)^-1)) sigma
(eq. 49, with the information matrix Q = J^T J of eq. 47; J is the regressor matrix of a
linear model). A design that cannot separate the parameters is refused by name.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from procedures.common.uncertainty import type_a_json
from station.least_squares import FitError

# Units of the static model's identified terms (seed 003 eq. 14; procedures.multiposition.static_model)
UNITS = {"k0+ky": "rad/s", "kz": "rad/s/g", "kzz-ky": "rad/s/g²", "koq": "rad/s/g²", "k3": "rad/s/g³"}

# Beyond this condition number of the column-scaled Jacobian the parameters are not separable in double precision.
MAX_CONDITION = 1e10
SEED003_TYPE_B = (
    "Type A only (the fit, k from Student's t at its dof; with compensation the angle-error harmonics are fitted "
    "with the coefficients, so their uncertainty is inside the covariance): latitude, g and the timer are not "
    "propagated here"
)


@dataclass(frozen=True)
class Fit:
    names: tuple[str, ...]
    values: np.ndarray
    cov: np.ndarray
    sigma_residual: float
    residuals: np.ndarray  # model minus measured, in the input order
    dof: int

    @property
    def sigmas(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def value(self, name: str) -> tuple[float, float]:
        i = self.names.index(name)
        return float(self.values[i]), float(self.sigmas[i])

    def to_json(self) -> dict:
        coefs = {n: {"value": float(v), "sigma": float(s)} for n, v, s in zip(self.names, self.values, self.sigmas,
                                                                               strict=True)}  # fmt: skip
        units = {n: UNITS.get(n.split(" ")[-1], "rad" if n[:1] in "cs" or "dtheta" in n else "") for n in self.names}
        gum = type_a_json(coefs, self.names, self.values, self.cov, self.dof, units, SEED003_TYPE_B)
        return {"coefficients": coefs, "sigma_residual_radps": self.sigma_residual, "dof": self.dof,
                "n": int(self.residuals.size), **gum}  # fmt: skip


def solve(
    residuals: Callable[[np.ndarray], np.ndarray],
    jacobian: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    names: tuple[str, ...],
) -> Fit:
    """Levenberg-Marquardt from x0; FitError if the data cannot identify every parameter."""
    n, p = residuals(x0).size, len(names)
    if n <= p:
        raise FitError(f"{n} windows cannot fit {p} parameters ({', '.join(names)})")
    r = least_squares(residuals, x0, jac=jacobian, method="lm", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    J = np.asarray(r.jac, dtype=float)
    scale = np.linalg.norm(J, axis=0)
    if np.any(scale == 0):
        raise FitError(f"no window excites {', '.join(np.asarray(names)[scale == 0])}")
    _, sv, vt = np.linalg.svd(J / scale, full_matrices=False)
    if sv[-1] <= sv[0] / MAX_CONDITION:
        weak = np.asarray(names)[np.abs(vt[-1]) > 0.3]
        raise FitError(f"the design cannot separate {', '.join(weak)} (condition number {sv[0] / sv[-1]:.3g})")
    dof = n - p
    sigma = math.sqrt(float(r.fun @ r.fun) / dof)
    inv = (vt.T / sv**2) @ vt
    cov = inv / np.outer(scale, scale) * sigma**2
    return Fit(tuple(names), np.asarray(r.x, dtype=float), cov, sigma, np.asarray(r.fun, dtype=float), dof)
