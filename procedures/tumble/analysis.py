"""Seed 001 estimators: the eight-point tumble (eq. 6) at each temperature, the temperature laws and the
hysteresis of eq. 4, from forward and back strokes in three cycles.

At each temperature the readings y (volts) of position J = 1..9 (head angle (J - 1) 45 deg; 9 is
1 after a full turn) in strokes k = 1..6 (odd forward, even back) are fitted by least squares as

    y = Y_J - K1 h b + d (t - t_mean) + e

b the hysteresis branch each reading was reached on (+1: aI last rose, -1: fell; from the head's
path, station.twin.pendulous_accelerometer.branch_after_move), d the bias drift (eq. 3's k0D).
The position levels Y_J and their covariance go through eq. 6, restated from eq. 5 with
accelerations in g (the seed's OCR garbles signs and factors; these combinations are exact for
eq. 1 sampled at the eight angles: it is the 8-point Fourier analysis of eq. 5):

    K0  = (Y3 + Y7) / 2
    K1  = [2 sqrt2 (Y2 + Y8 - Y4 - Y6) - (Y1 + Y9 - 2 Y5)] / 4
    K2  = (Y2 + Y4 + Y6 + Y8) / 2 - 2 K0
    K3  = (Y1 + Y9 - 2 Y5) / 2 - (Y2 + Y8 - Y4 - Y6) / sqrt2
    Mo  = (Y3 - Y7) / 2
    Mip = (Y2 + Y6 - Y4 - Y8) / 2

and k0 = K0 / K1, k2 = K2 / K1, k3 = K3 / K1, do = Mo / K1, dip = Mip / K1 (eq. 6, last line), with
uncertainties propagated to first order. Across temperatures, eq. 4's two-slope laws
k0 = k0N + lambda_T1(2) dT, K1 = K1N (1 + beta_T1(2) dT), do = doN + gamma_T1(2) dT (dT = T - T0
from the chamber's product temperature) are fitted by weighted least squares on those estimates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from procedures.common.references import Reference
from procedures.common.uncertainty import Budget, merged_json, transformed
from procedures.tumble.budget import eq6_budget
from station.least_squares import FitError, reliability
from station.records import Field, declare
from station.session import Session
from station.twin.pendulous_accelerometer import CF_NAMES, branch_after_move

READING = "tumble"  # Measurement kind of one voltmeter reading at a tumble position
SOAK = "soak"  # Measurement kind of a chamber soak (its temperature record)
declare(
    READING,
    [Field("block", "int64", "", lo=0, doc="the temperature's place in the session"),
     Field("J", "int64", "", lo=1, hi=9),
     Field("stroke", "int64", ""), Field("cycle", "int64", "", lo=0), Field("setpoint_c", "float64", "degC"),
     Field("position_deg", "float64", "deg"), Field("from_deg", "float64", "deg", doc="where the head came from"),
     Field("t_s", "float64", "s", doc="mid-reading, station time"), Field("volts", "float64", "V", doc="mean output"),
     Field("volts_sd", "float64", "V", lo=0.0, nullable=True), Field("samples", "int64", "", lo=1, nullable=True),
     Field("nplc", "float64", "PLC", lo=0.0, nullable=True), Field("range_v", "float64", "V", lo=0.0, nullable=True),
     Field("temperature_c", "float64", "degC", doc="chamber temperature at the reading")],
    arrays=[Field("volts", "float64", "V", doc="every sample of the reading")],
    doc="one voltmeter reading at a tumble position (seed 001 eqs. 4, 6)",
)  # fmt: skip
declare(
    SOAK,
    [Field("setpoint_c", "float64", "degC"), Field("ramp_c_per_min", "float64", "degC/min", lo=0.0),
     Field("soak_s", "float64", "s", lo=0.0), Field("settled_s", "float64", "s", doc="time to settle in the band")],
    arrays=[Field("t_s", "float64", "s"), Field("temperature_c", "float64", "degC")],
    doc="a chamber soak and its temperature record",
)  # fmt: skip
POSITIONS = 9
STEP_DEG = 45.0
R2 = math.sqrt(2.0)
# Eq. 6 restated (module docstring): rows K0, K1, K2, K3, Mo, Mip; columns Y1 .. Y9.
EQ6 = np.array(
    [
        [0, 0, 0.5, 0, 0, 0, 0.5, 0, 0],
        [-0.25, R2 / 2, 0, -R2 / 2, 0.5, -R2 / 2, 0, R2 / 2, -0.25],
        [0, 0.5, -1, 0.5, 0, 0.5, -1, 0.5, 0],
        [0.5, -1 / R2, 0, 1 / R2, -1, 1 / R2, 0, -1 / R2, 0.5],
        [0, 0, 0.5, 0, 0, 0, -0.5, 0, 0],
        [0, 0.5, 0, -0.5, 0, 0.5, 0, -0.5, 0],
    ]
)
ERROR_NAMES = ("k0", "k2", "k3", "delta_o", "delta_ip")  # eq. 6, last line: K0, K2, K3, Mo, Mip over K1
# Mip multiplies aI aP (eq. 1): V/g^2, and delta_ip = Mip / K1 is per g
CF_UNITS = {"K0": "V", "K1": "V/g", "K2": "V/g^2", "K3": "V/g^3", "Mo": "V/g", "Mip": "V/g^2"}
ERROR_UNITS = {"k0": "g", "k2": "g/g^2", "k3": "g/g^3", "delta_o": "rad", "delta_ip": "g/g^2"}
SEED001_TYPE_B = (
    "Type B propagated by refit (procedures.tumble.budget): the index head's angle error at each head angle, the "
    "voltmeter's gain and offset; local g is the unit of the inputs and the temperature reading does not enter "
    "eq. 6 (it places the block on eq. 4's laws)"
)
MIN_LEVER_C = 1.0  # a temperature law's slope needs a temperature at least this far from T0


@dataclass(frozen=True)
class LinearFit:
    values: np.ndarray
    cov: np.ndarray
    residuals: np.ndarray
    dof: int
    sigma: float  # residual standard deviation (OLS) or sqrt(chi2 / dof) (known sigmas)

    @property
    def sigmas(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))


def linear_fit(X: np.ndarray, y: np.ndarray, sigma_y: np.ndarray | None = None) -> LinearFit:
    """Least squares y = X beta; covariance from the residuals, or from known sigma_y (then absolute)."""
    n, p = X.shape
    w = np.ones(n) if sigma_y is None else 1.0 / np.asarray(sigma_y, dtype=float)
    Xw, yw = X * w[:, None], y * w
    if np.linalg.matrix_rank(Xw) < p:
        raise FitError(f"{n} readings cannot separate {p} parameters: the design is singular")
    beta, *_ = scipy.linalg.lstsq(Xw, yw)
    resid = y - X @ beta
    dof = n - p
    chi2 = float(np.sum((resid * w) ** 2))
    sigma = math.sqrt(chi2 / dof) if dof > 0 else 0.0
    cov = np.linalg.inv(Xw.T @ Xw) * (sigma**2 if sigma_y is None else 1.0)
    return LinearFit(beta, cov, resid, dof, sigma)


# ---------------------------------------------------------------- readings


def position_deg(J: int) -> float:
    """Head angle of test position J (Fig. 2: J = 1 input axis up, then every 45 deg; 9 = 1 after a turn)."""
    return (J - 1) * STEP_DEG


def stroke_sequence(cycles: int) -> list[tuple[int, int, int]]:
    """(cycle, stroke k, J) of the seed's test: per cycle the forward stroke J = 1 .. 9, then the back stroke
    J = 9 .. 1; k = 1, 3, 5 forward and 2, 4, 6 back in three cycles."""
    forward = list(range(1, POSITIONS + 1))
    return [
        (c, 2 * c - 1 + back, J)
        for c in range(1, cycles + 1)
        for back in (0, 1)
        for J in (forward[::-1] if back else forward)
    ]


@dataclass(frozen=True)
class Readings:
    """The tumble readings of one session, in order, as arrays."""

    block: np.ndarray  # which visit to a temperature (0, 1, ...): a temperature may be visited twice
    setpoint_c: np.ndarray
    temperature_c: np.ndarray  # chamber product temperature at each reading
    J: np.ndarray  # 1 .. 9
    stroke: np.ndarray  # k = 1 .. 6 within its temperature
    t_s: np.ndarray
    volts: np.ndarray
    branch: np.ndarray

    def of_block(self, block: int) -> Readings:
        keep = self.block == block
        return Readings(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))

    @property
    def blocks(self) -> list[int]:
        """The temperature blocks, in the order the session visited them."""
        return list(dict.fromkeys(self.block.tolist()))


def path_branches(from_deg: np.ndarray, to_deg: np.ndarray) -> np.ndarray:
    """The hysteresis branch of each reading from the head's moves, in session order (0 before any)."""
    out, b = np.zeros(len(to_deg)), 0.0
    for i, (a, z) in enumerate(zip(np.radians(from_deg), np.radians(to_deg), strict=True)):
        out[i] = b = branch_after_move(a, z, b)
    return out


def readings(session: Session) -> Readings:
    ms = [m for m in session.measurements if m.kind == READING]
    if not ms:
        raise FitError("the session holds no tumble readings")

    def col(name: str, dtype: type = float) -> np.ndarray:
        return np.array([m.values[name] for m in ms], dtype=dtype)

    return Readings(
        col("block", int),
        col("setpoint_c"),
        col("temperature_c"),
        col("J", int),
        col("stroke", int),
        col("t_s"),
        col("volts"),
        path_branches(col("from_deg"), col("position_deg")),
    )


# ---------------------------------------------------------------- one temperature


@dataclass(frozen=True)
class EightPoint:
    """Eq. 6 at one temperature, with the stroke fit it stands on."""

    block: int
    setpoint_c: float
    temperature_c: float
    t_mean_s: float  # the estimates hold at this station time (the stroke fit's drift is centred on it)
    n: int
    Y_v: np.ndarray  # position levels Y1 .. Y9
    cf: np.ndarray  # K0, K1, K2, K3, Mo, Mip (V/g^n)
    cf_cov: np.ndarray
    errors: np.ndarray  # k0, k2, k3, delta_o, delta_ip (g/g^n, rad)
    errors_cov: np.ndarray
    hysteresis_g: tuple[float, float]
    drift_g_per_s: tuple[float, float]
    sigma_v: float
    dof: int
    mu: float
    mu_c: float
    Y_sigma_v: np.ndarray
    residuals_v: np.ndarray  # of the stroke fit, reading by reading (y - Y_J + K1 h b - d t)
    budget: Budget  # GUM budget of K0 .. Mip (procedures.tumble.budget)

    def error_budget(self) -> Budget:
        """The budget of k0, k2, k3, delta_o, delta_ip = K / K1 (eq. 6, last line) from that of K0 .. Mip."""
        return transformed(self.budget, ERROR_NAMES, self.errors, ratio_jacobian(self.cf), ERROR_UNITS)

    def coefficient(self, name: str) -> tuple[float, float]:
        """(value, sigma) of a CF coefficient (K0 .. Mip) or an error-model coefficient (k0 .. delta_ip)."""
        if name in CF_NAMES:
            i = CF_NAMES.index(name)
            return float(self.cf[i]), float(math.sqrt(self.cf_cov[i, i]))
        i = ERROR_NAMES.index(name)
        return float(self.errors[i]), float(math.sqrt(self.errors_cov[i, i]))

    @property
    def k1_3sigma_ppm(self) -> float:
        """Scale factor instability as the seed quotes it: 3 sigma of the mean K1, relative (k1 of eq. 4)."""
        k1, s = self.coefficient("K1")
        return 3e6 * s / abs(k1)

    def to_json(self) -> dict:
        coef = {n: dict(zip(("value", "sigma"), self.coefficient(n), strict=True)) for n in CF_NAMES + ERROR_NAMES}
        return {
            "block": self.block,
            "setpoint_c": self.setpoint_c,
            "temperature_c": self.temperature_c,
            "t_mean_s": self.t_mean_s,
            "n_readings": self.n,
            "coefficients": coef,
            "Y_v": self.Y_v.tolist(),
            "Y_sigma_v": self.Y_sigma_v.tolist(),
            "hysteresis_g": dict(zip(("value", "sigma"), self.hysteresis_g, strict=True)),
            "drift_g_per_s": dict(zip(("value", "sigma"), self.drift_g_per_s, strict=True)),
            "k1_3sigma_ppm": self.k1_3sigma_ppm,
            "sigma_v": self.sigma_v,
            "dof": self.dof,
            "mu": self.mu,
            "mu_c": self.mu_c,
            "gum_cf": merged_json(coef, self.budget, SEED001_TYPE_B),
            "gum_errors": merged_json(coef, self.error_budget(), SEED001_TYPE_B),
        }


RATIO_OF = [0, 2, 3, 4, 5]  # K0, K2, K3, Mo, Mip over K1


def ratio_jacobian(cf: np.ndarray) -> np.ndarray:
    """d(K / K1)/d(K0 .. Mip) for K0, K2, K3, Mo, Mip (eq. 6, last line)."""
    k1 = cf[1]
    jac = np.zeros((len(RATIO_OF), len(cf)))
    jac[np.arange(len(RATIO_OF)), RATIO_OF] = 1.0 / k1
    jac[:, 1] = -cf[RATIO_OF] / k1**2
    return jac


def ratios(cf: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """k = K / K1 for K0, K2, K3, Mo, Mip (eq. 6, last line) and their covariance to first order."""
    jac = ratio_jacobian(cf)
    return cf[RATIO_OF] / cf[1], jac @ cov @ jac.T


def eight_point(block: Readings, references: Mapping[str, Reference] | None = None) -> EightPoint:
    """The stroke fit and eq. 6 for the readings of one temperature (its budget from `references`, default the
    shipped file)."""
    missing = sorted(set(range(1, POSITIONS + 1)) - set(block.J.tolist()))
    if missing:
        raise FitError(f"{block.setpoint_c[0]:g} C: no reading at position(s) J = {missing} (eq. 6 needs 1 .. 9)")
    t = block.t_s - block.t_s.mean()
    X = np.column_stack([np.eye(POSITIONS)[block.J - 1], -block.branch, t])
    fit = linear_fit(X, block.volts)
    Y, cov_Y = fit.values[:POSITIONS], fit.cov[:POSITIONS, :POSITIONS]
    cf, cf_cov = EQ6 @ Y, EQ6 @ cov_Y @ EQ6.T
    errors, errors_cov = ratios(cf, cf_cov)
    k1 = cf[1]
    h, d = fit.values[POSITIONS:] / k1
    s_h, s_d = fit.sigmas[POSITIONS:] / abs(k1)
    mu, mu_c = reliability(fit.residuals, fit.sigma)
    budget = eq6_budget(CF_NAMES, cf, cf_cov, fit.dof, CF_UNITS, block.volts, block.J,
                        lambda v: EQ6 @ linear_fit(X, v).values[:POSITIONS], references)  # fmt: skip
    return EightPoint(
        int(block.block[0]),
        float(block.setpoint_c[0]),
        float(block.temperature_c.mean()),
        float(block.t_s.mean()),
        len(block.volts),
        Y,
        cf,
        cf_cov,
        errors,
        errors_cov,
        (float(h), float(s_h)),
        (float(d), float(s_d)),
        fit.sigma,
        fit.dof,
        mu,
        mu_c,
        np.sqrt(np.diag(cov_Y)),
        fit.residuals,
        budget,
    )


# ---------------------------------------------------------------- across temperatures


@dataclass(frozen=True)
class TwoSlope:
    """value(dT, t) = at_reference + above dT (dT > 0) or below dT (dT < 0) [+ drift (t - t_first)], each
    (value, sigma); None where the session cannot tell (no temperature on that side, no repeated temperature)."""

    at_reference: tuple[float, float]
    above: tuple[float, float] | None = None
    below: tuple[float, float] | None = None
    drift_per_s: tuple[float, float] | None = None

    def to_json(self) -> dict:
        def pair(p):
            return None if p is None else {"value": p[0], "sigma": p[1]}

        return {"at_reference": pair(self.at_reference), "above": pair(self.above), "below": pair(self.below),
                "drift_per_s": pair(self.drift_per_s)}  # fmt: skip


def two_slope(
    dT_c: np.ndarray, values: np.ndarray, sigmas: np.ndarray, *, t_s: np.ndarray | None = None, relative: bool = False
) -> TwoSlope:
    """Eq. 4's law through per-temperature estimates (weighted LS with their sigmas). With the blocks' times t_s a
    linear drift is fitted too when the design separates it (a temperature visited twice). `relative` divides
    the slopes by the reference value (beta_T of K1), propagating its uncertainty."""
    dT = np.asarray(dT_c, dtype=float)
    above, below = bool(np.any(dT > MIN_LEVER_C)), bool(np.any(dT < -MIN_LEVER_C))
    columns = {"at_reference": np.ones_like(dT)}
    if above and below:
        columns |= {"above": np.maximum(dT, 0.0), "below": np.minimum(dT, 0.0)}
    elif above or below:  # one side: the temperatures near T0 belong to its slope
        columns["above" if above else "below"] = dT
    if t_s is not None:
        t = np.asarray(t_s, dtype=float) - t_s[0]
        if np.linalg.matrix_rank(np.column_stack([*columns.values(), t])) > len(columns):
            columns["drift_per_s"] = t
    fit = linear_fit(np.column_stack(list(columns.values())), np.asarray(values, dtype=float), sigmas)
    beta, cov = fit.values, fit.cov
    if relative:
        jac = np.eye(len(beta)) / beta[0]
        jac[1:, 0] = -beta[1:] / beta[0] ** 2
        jac[0] = 0.0
        jac[0, 0] = 1.0
        beta = np.concatenate([[beta[0]], beta[1:] / beta[0]])
        cov = jac @ cov @ jac.T
    pairs = zip(beta.tolist(), np.sqrt(np.diag(cov)).tolist(), strict=True)
    return TwoSlope(**dict(zip(columns, pairs, strict=True)))


@dataclass(frozen=True)
class TemperatureModel:
    """Eq. 4's temperature laws and the hysteresis over the session."""

    reference_c: float
    bias_g: TwoSlope  # k0N (at the first block's time), lambda_T1, lambda_T2, and k0D if separable
    scale_factor: TwoSlope  # K1N (V/g), beta_T1, beta_T2 (1/C)
    misalignment_rad: TwoSlope  # doN, gamma_T1, gamma_T2
    hysteresis_g: tuple[float, float]  # h_T, weighted over the temperatures

    def to_json(self) -> dict:
        return {
            "reference_c": self.reference_c,
            "bias_g": self.bias_g.to_json(),
            "scale_factor": self.scale_factor.to_json(),
            "misalignment_rad": self.misalignment_rad.to_json(),
            "hysteresis_g": {"value": self.hysteresis_g[0], "sigma": self.hysteresis_g[1]},
        }


def temperature_model(points: list[EightPoint], reference_c: float) -> TemperatureModel:
    """Eq. 4's laws through the eight-point results of every temperature (dT from the measured temperatures).

    The bias drifts (eq. 3's k0D) over the hours between temperatures; unless the session returns to a temperature
    to separate it, that drift is part of lambda_T (the seed's 2e-5 g in 12 h moves lambda_T by 0.03 ug/C per hour
    between blocks over a 60 C lever, as much as its sigma in a three-cycle session); a return to T0 removes it.
    """
    dT = np.array([p.temperature_c - reference_c for p in points])
    t_s = np.array([p.t_mean_s for p in points])

    def law(name: str, **kw) -> TwoSlope:
        v, s = np.array([p.coefficient(name) for p in points]).T
        return two_slope(dT, v, s, **kw)

    h, s = np.array([p.hysteresis_g for p in points]).T
    w = 1.0 / s**2
    return TemperatureModel(
        reference_c,
        law("k0", t_s=t_s),
        law("K1", relative=True),
        law("delta_o"),
        (float(np.sum(w * h) / np.sum(w)), float(1.0 / math.sqrt(np.sum(w)))),
    )


def analyse_tumble(
    session: Session, reference_c: float, references: Mapping[str, Reference] | None = None
) -> tuple[Readings, list[EightPoint], TemperatureModel]:
    """Every estimate of a tumble session: the readings, eq. 6 per temperature (budgets from `references`), eq. 4
    across them."""
    r = readings(session)
    points = [eight_point(r.of_block(b), references) for b in r.blocks]
    return r, points, temperature_model(points, reference_c)
