"""Coefficient identification from a recorded session (physics.md; seed 000 eqs. 19-22, 28-29, 35).

`integral`: the integral precession model with exact window means from t1,
t2 and Tm. `baseline`: the classical integer periodic vibration model (eq.
35), which drops the window-edge terms and so cannot see kz.

The baseline's coefficients carry a bias its U does not cover (physics.md, integer-period timing capture): once
a = A0 w^2 / g > 1 the window closes at the first passage of the precession angle, on the rising flank before a
per-period maximum, so the vibration phase at Tm is not uniform and the dropped window-edge terms are not zero;
seed 000 Table 10 shows it as k3 errors of +5.5e-7 to +9.5e-7 rad/s/g^3 (Ref. 22's method). The bias is stated
beside each baseline coefficient (`state_first_passage_bias`: the baseline minus the integral method on the same
data, whose exact window means hold for any root), not left out: the baseline exists to be compared (seed 000
6.2.2), a baseline k3 left out would hide that comparison, and a fit without k3 would move kzz and ky. It is not
corrected (corrected, the baseline would be the integral result) and not added to U (a known bias is not an
uncertainty, GUM 3.2.4): a reader sees value, U and the bias side by side.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from procedures.common.uncertainty import Budget
from station.least_squares import FitError, JointFit, fit_joint, reliability
from station.noise_form import form_covariance, form_fits, most_likely
from station.session import Session
from station.twin.regressors import (
    BASELINE_COEFFICIENTS,
    COEFFICIENTS,
    baseline_regressors,
    integral_regressors,
)
from station.twin.window_means import window_means

Method = Literal["integral", "baseline"]
COEFFICIENT_UNITS = {"kz": "rad/s/g", "kzz": "rad/s/g^2", "ky": "rad/s/g^2", "k3": "rad/s/g^3"}
METHODS: tuple[Method, ...] = ("integral", "baseline")
# White rate noise (f = 0) is kept unless l(f_best) - l(0) exceeds chi2_1(0.95) / 2: on a 6-position design the
# form is weakly identified and a free choice under-covers white noise (kzz's z spread 1.54 against 1.24, issue 32).
# The same rule as prior odds weighs white among the forms whose spread is the choice's uncertainty.
WHITE_REJECTED = 1.92
# A coefficient whose u the noise form's choice makes this many times the chosen form's or more is named in how the
# weights were chosen: smaller factors are lost in the spread of u itself (its relative sd 1/sqrt(2 dof), 19 % at 14).
FORM_NOTE_RATIO = 1.05


@dataclass(frozen=True)
class Compensation:
    """Measured table errors to compensate (seed 000 6.1): Zs1(w) in metres, axs1 in rad.

    The further fields are the inputs the uncertainty budget perturbs (procedures/integral_precession/budget.py):
    a measured frequency error eps_f (w = w_cmd (1 + eps_f)), the read-head latency (the
    reference crossings, so t1 and t2, are stamped late by it) and the A0 and g of the
    amplitude ratio a = A0 w^2 / g when they differ from the session's station values.
    """

    zs1_m: Callable[[float], float] | None = None
    axs1_rad: float = 0.0
    eps_f: float = 0.0
    latency_s: float = 0.0
    A0_m: float | None = None
    g_mps2: float | None = None


Weighting = Literal["auto", "equal"]


def point_weights(
    session: Session,
    weighting: Weighting = "auto",
    method: Method = "integral",
    compensation: Compensation | None = None,
) -> tuple[np.ndarray, str]:
    """Relative weights 1 / var of each measured rate for weighted least squares, and how they were chosen.

    A per-point `repeatability_radps` column (the stated one-sigma rate repeatability of that
    point) gives w = 1 / r^2; a session-wide `instrument_repeatability_radps` (physics.md: the
    same for every window) gives equal weights. Otherwise the form of the rate noise is chosen from
    the data (station.noise_form, as the gap diagnosis does): a constant per window, white rate noise
    (the variance of a window-mean rate goes as 1/Tm), or a mixture, T_ref the session's median window.
    The scale sigma is always estimated from the residuals (eq. 21), so only the ratios matter.
    """
    w, how, _choice = _weights_and_choice(session, weighting, method, compensation)
    return w, how


def _weights_and_choice(
    session: Session, weighting: Weighting, method: Method, compensation: Compensation | None, rows: tuple | None = None
) -> tuple[np.ndarray, str, np.ndarray | None]:
    """point_weights and, when the form was chosen from the data, the covariance of the estimates with the
    choice's uncertainty in it (station.noise_form.form_covariance), else None; `rows`: the session's `design`,
    when the caller has it."""
    pts = session.points
    if weighting == "equal":
        return np.ones(len(pts)), "equal weights (asked for)", None
    if weighting != "auto":
        raise ValueError(f"weighting {weighting!r} is not one of auto, equal")
    stated = [p.extra.get("repeatability_radps", "") for p in pts]
    if all(stated):
        r = np.array([float(v) for v in stated])
        if not np.all(np.isfinite(r) & (r > 0)):
            bad = [p.point_id for p, v in zip(pts, r, strict=True) if not (np.isfinite(v) and v > 0)]
            raise ValueError(f"repeatability_radps of points {bad}: expected finite values > 0 rad/s")
        return 1.0 / r**2, "1 / r^2 from each point's stated repeatability_radps", None
    if session.meta.get("instrument_repeatability_radps") is not None:
        how = "equal weights: instrument_repeatability_radps is stated, the same for every window"
        return np.ones(len(pts)), how, None
    tm = np.array([p.Tm_s for p in pts], dtype=float)
    rates, index, L, names, _vib = rows if rows is not None else design(session, method, compensation)
    ref_s = float(np.median(tm))
    fits = form_fits(rates, index, L, names, tm, ref_s)
    f = most_likely(fits)
    if fits[0.0].likelihood >= fits[f].likelihood - WHITE_REJECTED:
        f = 0.0
    w = 1.0 / fits[f].shape
    cov = form_covariance(fits, f, math.exp(WHITE_REJECTED))
    how = (
        f"w = 1 / (f + (1 - f) T_ref / Tm), f = {f:g} by profile likelihood (station.noise_form; white noise, "
        f"f = 0, unless the likelihood ratio rejects it at 5 %), T_ref = {ref_s:.4g} s: the rate noise is not "
        "stated; f = 0 is white noise (variance as 1/Tm), f = 1 a constant per window; covariance: each "
        "coefficient's variance the largest under the forms within the one-sigma likelihood interval of f, plus "
        "the likelihood-weighted spread of every f's estimates about this f's (the choice's uncertainty)"
        + _form_note(names, np.sqrt(np.diag(cov) / np.diag(fits[f].fit.cov)))
    )
    return w / w.mean(), how, cov


def _form_note(names: tuple[str, ...], ratios: np.ndarray) -> str:
    """What not knowing the noise form costs: the coefficients whose u it makes FORM_NOTE_RATIO times the chosen
    form's or more, and how a lab avoids it ('' if none)."""
    named = [f"{n} {r:.2f}" for n, r in zip(names, ratios, strict=True) if r >= FORM_NOTE_RATIO]
    if not named:
        return ""
    return (
        f"; the forms the data do not tell apart make u larger than the chosen form's by the factor "
        f"{', '.join(named)} (a stated repeatability or equal windows remove this)"
    )


@dataclass
class Identification:
    method: Method
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
    # seed 000 eqs. 21 and 28 exactly: OLS of Y on L, n = N = number of vibration test points
    sigma_Y_eq21: float = math.nan
    mu_eq28: float = math.nan
    mu_c_eq28: float = math.nan
    Y_residuals_eq21: np.ndarray = field(default_factory=lambda: np.zeros(0))
    weighting: str = ""
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))  # relative 1 / var of every measured rate
    budget: Budget | None = None
    # the baseline's first-passage bias per coefficient: (bias, its standard uncertainty); see the module docstring
    first_passage_bias: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def reliable(self) -> bool:
        """Eq. 28 as the seed defines it: mu < mu_c on the residuals of Y."""
        return bool(self.mu_eq28 < self.mu_c_eq28)

    def coefficient(self, name: str) -> tuple[float, float]:
        i = self.names.index(name)
        return float(self.values[i]), float(self.sigmas[i])

    def standard_uncertainties(self) -> np.ndarray:
        """u of each coefficient: the GUM budget's where there is one, else the fit's sigma."""
        return self.budget.standard_uncertainty() if self.budget is not None else self.sigmas

    def bias_note(self, name: str) -> str:
        """The first-passage bias of coefficient `name` in words, "" when none is stated."""
        if name not in self.first_passage_bias:
            return ""
        bias, u = self.first_passage_bias[name]
        return (f"first-passage bias {bias:+.2e} {COEFFICIENT_UNITS[name]} (u {u:.1e}; this baseline minus the "
                "integral method on the same data): not corrected, not in U")  # fmt: skip

    def to_json(self) -> dict:
        units = {**COEFFICIENT_UNITS, "sigma_residual": "rad/s", "sigma_Y_eq21": "rad/s"}
        coefs = {}
        gum = self.budget.coefficients_json() if self.budget is not None else {}
        for name in COEFFICIENTS:
            if name in self.names:
                v, s = self.coefficient(name)
                coefs[name] = {"value": v, "sigma": s, "unit": COEFFICIENT_UNITS[name], **gum.get(name, {})}
                if name in self.first_passage_bias:
                    bias, u = self.first_passage_bias[name]
                    coefs[name] |= {"first_passage_bias": bias, "first_passage_bias_u": u, "note": self.bias_note(name)}
            else:
                coefs[name] = {"value": None, "sigma": None, "note": f"not identifiable by the {self.method} model"}
        doc = {
            "method": self.method,
            "coefficients": coefs,
            "sigma_residual": self.sigma_residual,
            "sigma_residual_is": "the noise of one measured rate: sqrt(e^T W e / (n - p)) of the joint fit of all "
            f"{self.n_points} rates (static levels and coefficients), p = static levels + {len(self.names)}",
            "sigma_Y_eq21": self.sigma_Y_eq21,
            "sigma_Y_eq21_is": f"seed 000 eq. 21: sqrt(e^T e / (n - {len(self.names)})) of Y = vibration - static "
            f"rate, OLS on L (eq. 20), n = {len(self.vib_ids)} vibration points; Y carries its static point's noise",
            "mu": self.mu_eq28,
            "mu_c": self.mu_c_eq28,
            "reliable": self.reliable,
            "reliability_test": f"seed 000 eq. 28: mu = max|e| / sigma on the residuals of Y, "
            f"mu_c = 1.25 + ln sqrt(N / 3), N = {len(self.vib_ids)} test points",
            "mu_joint": self.mu,
            "mu_c_joint": self.mu_c,
            "mu_joint_is": "the variant on the joint fit's residuals of all rates, N = all points: a static rate's "
            "residual shares the errors of its vibration points, so max|e| / sigma there is about the seed's mu / "
            "sqrt(2) and N is larger; kept for comparison, the verdict is eq. 28's",
            "n_points": self.n_points,
            "dof": self.dof,
            "weighting": self.weighting,
            "units": units,
        }
        if self.budget is not None:
            b = self.budget.to_json()
            doc.update({"covariance": b["covariance"], "budget": b["budget"], "few_dof": b["few_dof"],
                        "min_reliable_dof": b["min_reliable_dof"]})  # fmt: skip
        else:
            doc["covariance"] = {"names": list(self.names), "matrix": self.cov.tolist()}
        return doc


def state_first_passage_bias(baseline: Identification, integral: Identification) -> None:
    """Set the baseline's first-passage bias of every coefficient both identify: the baseline's value minus the
    integral method's on the same session, u the two u in quadrature (their correlation neglected)."""
    if baseline.method != "baseline" or integral.method != "integral":
        raise ValueError(f"a first-passage bias compares a baseline with an integral identification, not "
                         f"{baseline.method} with {integral.method}")  # fmt: skip
    u_b, u_i = baseline.standard_uncertainties(), integral.standard_uncertainties()
    baseline.first_passage_bias = {
        n: (float(baseline.values[j] - integral.values[integral.names.index(n)]),
            math.hypot(float(u_b[j]), float(u_i[integral.names.index(n)])))
        for j, n in enumerate(baseline.names)
        if n in integral.names
    }  # fmt: skip


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
        w = 2 * math.pi * f * (1.0 + comp.eps_f)
        a0_m = session.station.A0_m if comp.A0_m is None else comp.A0_m
        g = session.station.g_mps2 if comp.g_mps2 is None else comp.g_mps2
        a = a0_m * w * w / g
        if comp.zs1_m is not None:
            a = a * (1.0 + np.array([comp.zs1_m(wi) for wi in w]) / a0_m)
        theta = np.radians([p.position_deg for p in vp])
        if method == "integral":
            Tm = np.array([p.Tm_s for p in vp])
            t1 = np.array([p.t1_s for p in vp], dtype=float) - comp.latency_s
            t2 = np.array([p.t2_s for p in vp], dtype=float) - comp.latency_s
            s1, s2, s3 = window_means(w, Tm, t1, t2)
            L[vib] = integral_regressors(theta, a, s1, s2, s3, comp.axs1_rad)
        else:
            L[vib] = baseline_regressors(theta, a)
    return rates, index, L, names, vib


def seed_eq28(Y: np.ndarray, L: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """Seed 000 eqs. 20, 21, 28 literally: K = (L^T L)^-1 L^T Y, e = Y - L K, sigma = sqrt(e^T e / (n - p)),
    mu = max|e| / sigma, mu_c = 1.25 + ln sqrt(N / 3) with N = n the number of test points (rows of Y)."""
    K, *_ = np.linalg.lstsq(L, Y, rcond=None)
    e = Y - L @ K
    n, p = L.shape
    sigma = math.sqrt(float(e @ e) / (n - p)) if n > p else math.nan
    mu, mu_c = reliability(e, sigma) if n > p else (math.inf, math.nan)
    return e, sigma, mu, mu_c


def identify(
    session: Session,
    method: Method = "integral",
    compensation: Compensation | None = None,
    weighting: Weighting = "auto",
) -> Identification:
    """Fit the session (weighted joint least squares) and evaluate it (eqs. 21, 22, 28, 29)."""
    rates, index, L, names, vib = design(session, method, compensation)
    if not vib.any():
        raise FitError("the session has no vibration points: the nonlinear coefficients need vibration")
    weights, how, form_cov = _weights_and_choice(
        session, weighting, method, compensation, (rates, index, L, names, vib)
    )
    fit: JointFit = fit_joint(rates, index, L, names, weights=weights)
    cov = fit.cov if form_cov is None else form_cov
    mu, mu_c = reliability(fit.residuals * np.sqrt(weights), fit.sigma_residual)
    pts = session.points
    Y = rates[vib] - fit.static_levels[index[vib]]
    y_res = Y - L[vib] @ fit.values
    static_rate = {int(i): r for i, r, v in zip(index, rates, vib, strict=True) if not v}
    Y_seed = rates[vib] - np.array([static_rate[int(i)] for i in index[vib]])
    e_seed, sigma_y, mu_seed, mu_c_seed = seed_eq28(Y_seed, L[vib])
    theta = np.radians([p.position_deg for p, v in zip(pts, vib, strict=True) if v])
    a = session.station.amplitude_ratio([p.freq_hz for p, v in zip(pts, vib, strict=True) if v])
    with np.errstate(divide="ignore"):
        prop = y_res / (a * np.abs(np.cos(theta)))
    return Identification(
        method=method,
        names=names,
        values=fit.values,
        sigmas=np.sqrt(np.diag(cov)),
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
        cov=cov,
        sigma_Y_eq21=sigma_y,
        mu_eq28=mu_seed,
        mu_c_eq28=mu_c_seed,
        Y_residuals_eq21=e_seed,
        weighting=how,
        weights=weights,
    )
