"""Joint fit of candidate effects with the calibrated coefficients (never to a frozen residual).

Model of every recorded rate (station.gap.forward):

    wbar_i = k0 + base_i(p) + units_i(p) . K          (K = kz, kzz, ky, k3)

of every period identity, tau_i = Np_i (T_true - T_cmd)(p), and of the grating's
harmonics at every point with a raw record (station.gap.rawstreams.GratingRecord): rate
rows, then timing rows, then grating rows, each whitened by its own noise. For given
effect parameters p the bias k0 (the one free level) and K follow by the weighted joint
least squares of station.least_squares.fit_joint (weights from
station.gap.noise), so the calibrated terms are refitted at every p (variable
projection). p is fitted with finite-difference columns of the exact forward
model: the columns at the twin's own values are computed once per session
(`Linearisation`) and give every candidate a first linear step, which is the
solution when the model is linear over it; otherwise
scipy.optimize.least_squares (Levenberg-Marquardt) takes over.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from station.gap import candidates as cl
from station.gap.design import PointDesign
from station.gap.forward import CALIBRATED, Prediction, period_identity_s, predict, predict_full
from station.gap.rawstreams import GratingRecord, PulseRecord
from station.least_squares import JointFit, fit_joint
from station.twin.config import TwinConfig

# Stop when the whitened sum of squares changes by less than 1e-4 of itself (a few 1e-3 of one
# noise variance) or the parameters by less than 1e-4 of their size.
_FTOL = 1e-4
_XTOL = 1e-4
# A linear step is the solution when the exact sum of squares is its prediction to 1 % of one
# residual variance: the objective is then quadratic over the step.
_LINEAR_RTOL = 0.01


@dataclass(frozen=True)
class Channels:
    """The observations of one session and how they are whitened."""

    design: PointDesign
    twin: TwinConfig
    weights: np.ndarray  # sigma0^2 / var(wbar_i) (station.gap.noise.rate_weights)
    sigma0_radps: float  # rate noise at T_ref used for whitening
    sigma_tau_s: float
    grating: GratingRecord | None = None
    constant_fraction: float = 0.0  # of the rate variance (station.gap.noise)
    rate_sigma_known: bool = False  # stated by the session: chi-square tests of the rate rows
    tau_sigma_known: bool = False
    pulses: PulseRecord | None = None  # rate harmonics of the pulse edges: tested (station.gap.localise), not fitted

    @property
    def n_rate(self) -> int:
        return self.design.n_points

    @property
    def n_tau(self) -> int:
        return int(self.design.vib.sum())

    @property
    def n_grating(self) -> int:
        return 0 if self.grating is None else self.grating.n_rows

    @property
    def n_other(self) -> int:
        """Rows after the rate rows: period identities, then grating harmonics."""
        return self.n_tau + self.n_grating

    def other_white(self, cfg: TwinConfig) -> np.ndarray:
        """Whitened predictions of the timing and grating rows under cfg."""
        d = self.design
        tau = self.white_tau(period_identity_s(d, cfg)[d.vib])
        if self.grating is None:
            return tau
        return np.concatenate([tau, self.grating.white(self.grating.predict(cfg))])

    def other_observed_white(self) -> np.ndarray:
        d = self.design
        tau = self.white_tau(d.tau_s[d.vib])
        return tau if self.grating is None else np.concatenate([tau, self.grating.observed_white()])

    def white_rate(self, r_radps: np.ndarray) -> np.ndarray:
        """Rows of rate residuals (or of a Jacobian) divided by each point's sigma."""
        w = np.sqrt(self.weights) / self.sigma0_radps
        return r_radps * (w if np.ndim(r_radps) == 1 else w[:, None])

    def white_tau(self, r_s: np.ndarray) -> np.ndarray:
        return r_s / self.sigma_tau_s


@dataclass(frozen=True)
class State:
    """The exact model at one parameter point, the calibrated terms refitted."""

    cfg: TwinConfig
    pred: Prediction
    lin: JointFit
    X_white: np.ndarray  # whitened linear design (levels, K), rate rows then zero timing rows
    r_white: np.ndarray  # whitened residual, rate rows then timing rows

    @property
    def rss_white(self) -> float:
        return float(self.r_white @ self.r_white)


def evaluate(ch: Channels, cfg: TwinConfig) -> State:
    """Predict, refit the bias k0 and K (fit_joint), and whiten the residuals."""
    d = ch.design
    pred = predict(d, cfg)
    lin = fit_joint(d.rate_radps - pred.base_radps, d.level_index, pred.units_radps, CALIBRATED, ch.weights)
    X_white = linear_design(ch, pred)
    r = np.concatenate([ch.white_rate(lin.residuals), ch.other_observed_white() - ch.other_white(cfg)])
    return State(cfg, pred, lin, X_white, r)


def linear_design(ch: Channels, pred: Prediction) -> np.ndarray:
    """Whitened columns of the bias k0 and K: rate rows, then zero timing rows."""
    d = ch.design
    X = np.hstack([np.eye(d.n_levels)[d.level_index], pred.units_radps])
    return np.vstack([ch.white_rate(X), np.zeros((ch.n_other, X.shape[1]))])


def model_columns(ch: Channels, K: np.ndarray, cfg_of, steps: Sequence[float]) -> np.ndarray:
    """Whitened d(prediction)/d(parameter) at fixed levels and K, by forward differences.

    cfg_of(j, h) is the twin with parameter j moved by h (parameter units).
    """
    d = ch.design
    cols = np.empty((ch.n_rate + ch.n_other, len(steps)))
    if not steps:
        return cols
    cfg0 = cfg_of(0, 0.0)
    full0, _ = predict_full(d, cfg0, K)
    other0 = ch.other_white(cfg0)
    for j, h in enumerate(steps):
        cfg = cfg_of(j, h)
        full, _ = predict_full(d, cfg, K)
        cols[:, j] = np.concatenate([ch.white_rate((full - full0) / h), (ch.other_white(cfg) - other0) / h])
    return cols


class Linearisation:
    """Finite-difference columns of every library parameter at the twin's own values.

    Computed once per session; shared by the identifiability check, the first
    Gauss-Newton step of every candidate and the held-out refits.
    """

    def __init__(self, ch: Channels, cands: Sequence[cl.Candidate]) -> None:
        self.ch = ch
        self.cands = {c.name: c for c in cands}
        self.fixed = {c.name: cl.fixed_params(c, ch.twin) for c in cands}
        self.params: list[cl.FreeParam] = [fp for c in cands for fp in c.free]
        self.p0 = {fp.key: v for fp, v in zip(self.params, cl.twin_values(ch.twin, self.params), strict=True)}
        # The twin with the fixed parameters set (lateral L0: no change while kx is the twin's).
        base_cfg = cl.apply(ch.twin, [], [], self.fixed)
        self.base_cfg = base_cfg
        self.state = evaluate(ch, base_cfg)
        self.n_rows = self.state.r_white.size

        def cfg_of(j: int, h: float) -> TwinConfig:
            fp = self.params[j]
            return cl.apply(base_cfg, [fp], [self.p0[fp.key] + h], {})

        cols = model_columns(ch, self.state.lin.values, cfg_of, [fp.fd_step for fp in self.params])
        self.columns = {fp.key: cols[:, j] for j, fp in enumerate(self.params)}
        Xs = self.state.X_white[: ch.n_rate]
        Q, _ = np.linalg.qr(Xs / np.linalg.norm(Xs, axis=0))
        self.Q = np.vstack([Q, np.zeros((ch.n_other, Q.shape[1]))])
        n_lev = ch.design.n_levels
        L = Xs[:, :n_lev]
        self.Q_levels = np.vstack([L / np.linalg.norm(L, axis=0), np.zeros((ch.n_other, n_lev))])

    def param(self, key: str) -> cl.FreeParam:
        return next(fp for fp in self.params if fp.key == key)

    def project(self, M: np.ndarray) -> np.ndarray:
        """Remove the part of the columns that the bias k0 and calibrated terms absorb."""
        return M - self.Q @ (self.Q.T @ M)

    def project_levels(self, M: np.ndarray) -> np.ndarray:
        """Remove only the constant (what the bias k0 absorbs)."""
        return M - self.Q_levels @ (self.Q_levels.T @ M)


@dataclass
class ModelFit:
    """A fitted model: twin + effects, with the calibrated coefficients refitted."""

    free: tuple[cl.FreeParam, ...]
    values: np.ndarray  # free parameters, parameter units
    sigmas: np.ndarray
    cfg: TwinConfig  # the twin with the fitted effects switched on
    K: np.ndarray
    K_sigmas: np.ndarray
    rate_resid_radps: np.ndarray
    tau_resid_s: np.ndarray  # vibration points only
    rss_rate: float  # sum w e^2, (rad/s)^2
    dof_rate: int
    chi2_tau: float  # sum (e / sigma_tau)^2
    chi2_grating: float  # sum (e / se)^2 of the grating harmonics (0 without raw records)
    J: np.ndarray  # whitened Jacobian (rate rows, then timing rows) x (levels, K, free)
    r_white: np.ndarray
    converged: bool  # least_squares met its tolerances
    n_rate_params: int
    cov: np.ndarray  # of (levels, K, free parameters in units of their scale), rate rows in this fit's sigma0

    @property
    def sigma0_hat_radps(self) -> float:
        return math.sqrt(self.rss_rate / self.dof_rate) if self.dof_rate > 0 else math.nan

    def refitted_cfg(self) -> TwinConfig:
        """The fitted twin with its calibrated coefficients K set to their refitted values."""
        values = dict(zip(CALIBRATED, map(float, self.K), strict=True))
        return replace(self.cfg, instrument=replace(self.cfg.instrument, **values))

    def effect_parameters(self, effect: str) -> tuple[dict[str, float], dict[str, float]]:
        """Fitted values and standard uncertainties of one effect's free parameters."""
        rows = zip(self.free, self.values, self.sigmas, strict=True)
        mine = [(fp.param, v, sd) for fp, v, sd in rows if fp.effect == effect]
        return {k: float(v) for k, v, _ in mine}, {k: float(sd) for k, _, sd in mine}


def fit_model(
    lin: Linearisation,
    names: Sequence[str],
    drop: frozenset[str] = frozenset(),
    fixed_override: Mapping[str, Mapping[str, float]] | None = None,
) -> ModelFit:
    """Fit the twin with candidates `names` switched on; parameters in `drop` stay at the twin's value.

    From the twin's own values, one linear least-squares step on the linearisation's columns; if
    the exact model then meets its linear prediction (within _LINEAR_RTOL of one residual
    variance), the model is linear there and that step is the solution. Otherwise
    scipy.optimize.least_squares (Levenberg-Marquardt) on the residual with the bias k0 and K
    refitted at every point (variable projection); its Jacobian is the model columns projected off
    the levels and K (Kaufman's approximation).
    """
    ch = lin.ch
    cands = [lin.cands[n] for n in names]
    free = tuple(fp for c in cands for fp in c.free if fp.key not in drop)
    override = fixed_override or {}
    fixed = {c.name: {**lin.fixed[c.name], **override.get(c.name, {})} for c in cands}
    p0 = np.array([lin.p0[fp.key] for fp in free])
    scale = np.array([fp.scale for fp in free])
    u0 = np.zeros(len(free))
    if not free:
        return _finish(ch, free, p0, scale, u0, lin.state, np.zeros((lin.n_rows, 0)), True)
    states: dict[bytes, State] = {}
    columns: dict[bytes, np.ndarray] = {}

    def cfg_at(u: np.ndarray) -> TwinConfig:
        return cl.apply(lin.base_cfg, free, p0 + scale * u, fixed)

    def state_at(u: np.ndarray) -> State:
        if u.tobytes() not in states:
            states[u.tobytes()] = lin.state if not np.any(u) else evaluate(ch, cfg_at(u))
        return states[u.tobytes()]

    def columns_at(u: np.ndarray) -> np.ndarray:
        """Whitened model columns per unit of u (at the twin's own values: from the linearisation)."""
        if u.tobytes() not in columns:
            if np.any(u) or any(fp.effect in override for fp in free):
                columns[u.tobytes()] = _columns_at(ch, state_at(u), cfg_at, u, free, scale)
            else:
                columns[u.tobytes()] = np.column_stack([lin.columns[fp.key] for fp in free]) * scale
        return columns[u.tobytes()]

    def jac(u: np.ndarray) -> np.ndarray:
        J, P = columns_at(u), _projector(state_at(u))
        return -(J - P @ (P.T @ J))

    A, r0 = jac(u0), lin.state.r_white
    u1 = np.linalg.lstsq(A, -r0, rcond=None)[0]
    predicted = float(np.sum((r0 + A @ u1) ** 2))
    dof = max(r0.size - lin.state.X_white.shape[1] - u1.size, 1)
    if abs(state_at(u1).rss_white - predicted) <= _LINEAR_RTOL * predicted / dof:
        return _finish(ch, free, p0, scale, u1, state_at(u1), columns_at(u0), True)
    res = least_squares(lambda u: state_at(u).r_white, u1, jac=jac, method="lm", ftol=_FTOL, xtol=_XTOL)
    return _finish(ch, free, p0, scale, res.x, state_at(res.x), columns_at(res.x), bool(res.success))


def _projector(state: State) -> np.ndarray:
    X = state.X_white
    norms = np.linalg.norm(X, axis=0)
    Q, _ = np.linalg.qr(X / np.where(norms > 0, norms, 1.0))
    return Q


def _columns_at(ch, state, cfg_at, u, free, scale) -> np.ndarray:
    """Model columns in u units at u (steps of fd_step in parameter units)."""
    steps = [fp.fd_step for fp in free]

    def cfg_of(j: int, h: float) -> TwinConfig:
        du = np.zeros_like(u)
        du[j] = h / scale[j]
        return cfg_at(u + du)

    return model_columns(ch, state.lin.values, cfg_of, steps) * scale


def _finish(ch, free, p0, scale, u, state: State, J_u, converged: bool) -> ModelFit:
    d = ch.design
    n_pos = d.n_levels
    J = np.hstack([state.X_white, J_u])
    lin = state.lin
    rss = float(np.sum(ch.weights * lin.residuals**2))
    n_rate_free = sum(1 for fp in free if not fp.timing)
    n_rate_params = n_pos + len(CALIBRATED) + n_rate_free
    dof = d.n_points - n_rate_params
    # Rate rows re-whitened by this model's own sigma0 estimate for the uncertainties.
    s_ratio = math.sqrt(rss / dof) / ch.sigma0_radps if dof > 0 else 1.0
    Jc = J.copy()
    Jc[: ch.n_rate] /= max(s_ratio, 1e-300)
    cov = _covariance(Jc)
    k = slice(n_pos, n_pos + len(CALIBRATED))
    uu = slice(n_pos + len(CALIBRATED), J.shape[1])
    sd_u = np.sqrt(np.clip(np.diag(cov[uu, uu]), 0, None))
    tau_res = d.tau_s[d.vib] - state.pred.tau_s[d.vib]
    return ModelFit(
        free=free,
        values=p0 + scale * u,
        sigmas=sd_u * scale,
        cfg=state.cfg,
        K=lin.values,
        K_sigmas=np.sqrt(np.clip(np.diag(cov[k, k]), 0, None)),
        rate_resid_radps=lin.residuals,
        tau_resid_s=tau_res,
        rss_rate=rss,
        dof_rate=dof,
        chi2_tau=float(np.sum(ch.white_tau(tau_res) ** 2)),
        chi2_grating=float(np.sum(state.r_white[ch.n_rate + ch.n_tau :] ** 2)),
        J=J,
        r_white=state.r_white,
        converged=converged,
        n_rate_params=n_rate_params,
        cov=cov,
    )


def _covariance(J: np.ndarray) -> np.ndarray:
    """(J^T J)^-1 of a whitened Jacobian, column-scaled for conditioning."""
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms
    return np.linalg.pinv(Js.T @ Js, rcond=1e-13) / np.outer(norms, norms)
