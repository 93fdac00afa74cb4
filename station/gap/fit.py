"""Joint fit of candidate effects with the calibrated coefficients (never to a frozen residual).

Model of every recorded rate (station.gap.forward):

    wbar_i = c_pos(i) + base_i(p) + units_i(p) . K          (K = kz, kzz, ky, k3)

and of every period identity, tau_i = Np_i (T_true - T_cmd)(p). For given
effect parameters p the static levels c and K follow by the weighted joint
least squares of station.analysis.least_squares.fit_joint (weights Tm / T_ref,
station.gap.noise), so the calibrated terms are refitted at every p
(variable projection). p is fitted by Gauss-Newton on the projected residual
with finite-difference columns of the exact forward model: the columns at the
twin's own values are computed once per session (`Linearisation`) and reused
by every candidate; after each step the exact model is evaluated again, and
while the linear prediction of the residual misses the exact one the columns
are recomputed at the new point; if that does not settle, the fit is handed
to scipy.optimize.least_squares (method "lm").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from station.analysis.least_squares import JointFit, fit_joint
from station.gap import candidates as cl
from station.gap.design import PointDesign
from station.gap.forward import CALIBRATED, Prediction, predict, predict_full
from station.twin.config import TwinConfig

# Gauss-Newton is accepted when the exact residual sum of squares (whitened) is within
# this of the linear prediction: far below the 1-unit scale of one noise standard deviation.
_LINEARITY_TOL = 0.05
_CONVERGED_GAIN = 0.01  # a Gauss-Newton step that gains less (whitened RSS) has converged
_MAX_RELINEARISE = 6
_RCOND = 1e-3  # relative singular value below which a combination of parameters is not moved


@dataclass(frozen=True)
class Channels:
    """The observations of one session and how they are whitened."""

    design: PointDesign
    twin: TwinConfig
    weights: np.ndarray  # Tm / T_ref
    sigma0_radps: float  # rate noise at T_ref used for whitening
    sigma_tau_s: float

    @property
    def n_rate(self) -> int:
        return self.design.n_points

    @property
    def n_tau(self) -> int:
        return int(self.design.vib.sum())

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
    """Predict, refit static levels and K (fit_joint), and whiten the residuals."""
    d = ch.design
    pred = predict(d, cfg)
    lin = fit_joint(d.rate_radps - pred.base_radps, d.pos_index, pred.units_radps, CALIBRATED, ch.weights)
    X_white = linear_design(ch, pred)
    r = np.concatenate([ch.white_rate(lin.residuals), ch.white_tau(d.tau_s[d.vib] - pred.tau_s[d.vib])])
    return State(cfg, pred, lin, X_white, r)


def linear_design(ch: Channels, pred: Prediction) -> np.ndarray:
    """Whitened columns of the static levels and K: rate rows, then zero timing rows."""
    d = ch.design
    X = np.hstack([np.eye(d.positions_deg.size)[d.pos_index], pred.units_radps])
    return np.vstack([ch.white_rate(X), np.zeros((ch.n_tau, X.shape[1]))])


def model_columns(ch: Channels, K: np.ndarray, cfg_of, steps: Sequence[float]) -> np.ndarray:
    """Whitened d(prediction)/d(parameter) at fixed levels and K, by forward differences.

    cfg_of(j, h) is the twin with parameter j moved by h (parameter units).
    """
    d = ch.design
    cols = np.empty((ch.n_rate + ch.n_tau, len(steps)))
    if not steps:
        return cols
    full0, tau0 = predict_full(d, cfg_of(0, 0.0), K)
    for j, h in enumerate(steps):
        full, tau = predict_full(d, cfg_of(j, h), K)
        cols[:, j] = np.concatenate(
            [
                ch.white_rate((full - full0) / h),
                ch.white_tau((tau[d.vib] - tau0[d.vib]) / h),
            ]
        )
    return cols


class Linearisation:
    """Finite-difference columns of every library parameter at the twin's own values.

    Computed once per session; shared by the identifiability check, the first
    Gauss-Newton step of every candidate and the held-out refits.
    """

    def __init__(self, ch: Channels, cands: Sequence[cl.Candidate]) -> None:
        self.ch = ch
        self.state = evaluate(ch, ch.twin)
        self.cands = {c.name: c for c in cands}
        self.fixed = {c.name: cl.fixed_params(c, ch.twin) for c in cands}
        self.params: list[cl.FreeParam] = [fp for c in cands for fp in c.free]
        self.p0 = {fp.key: v for fp, v in zip(self.params, cl.twin_values(ch.twin, self.params), strict=True)}
        base_cfg = cl.apply(ch.twin, [], [], self.fixed)
        self.base_cfg = base_cfg
        if base_cfg != ch.twin:  # fixed parameters (lateral L0) change nothing at kx = 0, but be exact
            self.state = evaluate(ch, base_cfg)
        self.n_rows = self.state.r_white.size

        def cfg_of(j: int, h: float) -> TwinConfig:
            fp = self.params[j]
            return cl.apply(base_cfg, [fp], [self.p0[fp.key] + h], {})

        cols = model_columns(ch, self.state.lin.values, cfg_of, [fp.fd_step for fp in self.params])
        self.columns = {fp.key: cols[:, j] for j, fp in enumerate(self.params)}
        Xs = self.state.X_white[: ch.n_rate]
        Q, _ = np.linalg.qr(Xs / np.linalg.norm(Xs, axis=0))
        self.Q = np.vstack([Q, np.zeros((ch.n_tau, Q.shape[1]))])
        n_pos = ch.design.positions_deg.size
        L = Xs[:, :n_pos]
        self.Q_levels = np.vstack([L / np.linalg.norm(L, axis=0), np.zeros((ch.n_tau, n_pos))])

    def param(self, key: str) -> cl.FreeParam:
        return next(fp for fp in self.params if fp.key == key)

    def project(self, M: np.ndarray) -> np.ndarray:
        """Remove the part of the columns that the static levels and calibrated terms absorb."""
        return M - self.Q @ (self.Q.T @ M)

    def project_levels(self, M: np.ndarray) -> np.ndarray:
        """Remove only the per-position constants (what every static level absorbs)."""
        return M - self.Q_levels @ (self.Q_levels.T @ M)


@dataclass
class ModelFit:
    """A fitted model: twin + effects, with the calibrated coefficients refitted."""

    effects: tuple[str, ...]
    free: tuple[cl.FreeParam, ...]
    values: np.ndarray  # free parameters, parameter units
    sigmas: np.ndarray
    cfg: TwinConfig  # the twin with the fitted effects switched on
    K: np.ndarray
    K_sigmas: np.ndarray
    levels_radps: np.ndarray
    rate_resid_radps: np.ndarray
    tau_resid_s: np.ndarray  # vibration points only
    rss_rate: float  # sum w e^2, (rad/s)^2
    dof_rate: int
    chi2_tau: float  # sum (e / sigma_tau)^2
    J: np.ndarray  # whitened Jacobian (rate rows, then timing rows) x (levels, K, free)
    r_white: np.ndarray
    converged: bool
    corr: np.ndarray  # correlation matrix of the free parameters
    n_rate_params: int

    @property
    def sigma0_hat_radps(self) -> float:
        return math.sqrt(self.rss_rate / self.dof_rate) if self.dof_rate > 0 else math.nan

    def effect_parameters(self, effect: str) -> tuple[dict[str, float], dict[str, float]]:
        """Fitted values and standard uncertainties of one effect's free parameters."""
        rows = zip(self.free, self.values, self.sigmas, strict=True)
        mine = [(fp.param, v, sd) for fp, v, sd in rows if fp.effect == effect]
        return {k: float(v) for k, v, _ in mine}, {k: float(sd) for k, _, sd in mine}


def fit_model(
    lin: Linearisation,
    names: Sequence[str],
    drop: frozenset[str] = frozenset(),
    start: Mapping[str, float] | None = None,
) -> ModelFit:
    """Fit the twin with candidates `names` switched on; parameters in `drop` stay at the twin's value."""
    ch = lin.ch
    cands = [lin.cands[n] for n in names]
    free = tuple(fp for c in cands for fp in c.free if fp.key not in drop)
    fixed = {c.name: lin.fixed[c.name] for c in cands}
    p0 = np.array([lin.p0[fp.key] for fp in free])
    scale = np.array([fp.scale for fp in free])

    def cfg_at(u: np.ndarray) -> TwinConfig:
        return cl.apply(lin.base_cfg, free, p0 + scale * u, fixed)

    u = np.zeros(len(free))
    for j, fp in enumerate(free):
        if start and fp.key in start:
            u[j] = (start[fp.key] - p0[j]) / scale[j]
    state = lin.state if not np.any(u) else evaluate(ch, cfg_at(u))
    J_u = np.column_stack([lin.columns[fp.key] for fp in free]) * scale if free else np.zeros((state.r_white.size, 0))
    if np.any(u):
        J_u = _columns_at(ch, state, cfg_at, u, free, scale)
    converged = not free
    for _ in range(_MAX_RELINEARISE + 1):
        if not free:
            break
        P = _projector(state)
        A = J_u - P @ (P.T @ J_u)
        du = _solve(A, state.r_white)
        predicted = float(np.sum((state.r_white - A @ du) ** 2))
        new = evaluate(ch, cfg_at(u + du))
        if new.rss_white > state.rss_white + _LINEARITY_TOL:
            break  # the linear step overshoots: hand over to least_squares
        gain = state.rss_white - new.rss_white
        u, state = u + du, new
        if abs(new.rss_white - predicted) <= _LINEARITY_TOL + 1e-6 * predicted or gain < _CONVERGED_GAIN:
            converged = True
            break
        J_u = _columns_at(ch, state, cfg_at, u, free, scale)
    if not converged:
        u, state, converged = _least_squares(ch, cfg_at, u, free, scale)
        J_u = _columns_at(ch, state, cfg_at, u, free, scale)
    return _finish(ch, tuple(names), free, p0, scale, u, state, J_u, converged)


def _solve(A: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Least-squares step, columns scaled to unit norm; directions the data cannot see are not moved."""
    norms = np.linalg.norm(A, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    x, *_ = np.linalg.lstsq(A / norms, r, rcond=_RCOND)
    return x / norms


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


def _least_squares(ch, cfg_at, u0, free, scale):
    """Fallback for strongly nonlinear cases: scipy least_squares ("lm") on the projected residual.

    Its Jacobian is the projected model columns (variable projection with
    Kaufman's approximation), one twin evaluation per parameter.
    """
    cache: dict[str, State] = {}

    def fun(u: np.ndarray) -> np.ndarray:
        st = evaluate(ch, cfg_at(u))
        cache["u"], cache["s"] = u.copy(), st
        return st.r_white

    def jac(u: np.ndarray) -> np.ndarray:
        st = cache["s"] if "u" in cache and np.array_equal(cache["u"], u) else evaluate(ch, cfg_at(u))
        J = _columns_at(ch, st, cfg_at, u, free, scale)
        P = _projector(st)
        return -(J - P @ (P.T @ J))

    res = least_squares(fun, u0, jac=jac, method="lm", x_scale=1.0, max_nfev=30)
    return res.x, evaluate(ch, cfg_at(res.x)), bool(res.success)


def _finish(ch, names, free, p0, scale, u, state: State, J_u, converged) -> ModelFit:
    d = ch.design
    n_pos = d.positions_deg.size
    J = np.hstack([state.X_white, J_u])
    lin = state.lin
    rss = float(np.sum(ch.weights * lin.residuals**2))
    n_rate_free = sum(1 for fp in free if fp.effect != "frequency_error")
    n_rate_params = n_pos + len(CALIBRATED) + n_rate_free
    dof = d.n_points - n_rate_params
    # Rate rows re-whitened by this model's own sigma0 estimate for the uncertainties.
    s_ratio = math.sqrt(rss / dof) / ch.sigma0_radps if dof > 0 else 1.0
    Jc = J.copy()
    Jc[: ch.n_rate] /= max(s_ratio, 1e-300)
    cov = _covariance(Jc)
    k = slice(n_pos, n_pos + len(CALIBRATED))
    uu = slice(n_pos + len(CALIBRATED), J.shape[1])
    cov_u = cov[uu, uu]
    sd_u = np.sqrt(np.clip(np.diag(cov_u), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_u / np.outer(sd_u, sd_u)
    tau_res = d.tau_s[d.vib] - state.pred.tau_s[d.vib]
    return ModelFit(
        effects=names,
        free=free,
        values=p0 + scale * u,
        sigmas=sd_u * scale,
        cfg=state.cfg,
        K=lin.values,
        K_sigmas=np.sqrt(np.clip(np.diag(cov[k, k]), 0, None)),
        levels_radps=lin.static_levels,
        rate_resid_radps=lin.residuals,
        tau_resid_s=tau_res,
        rss_rate=rss,
        dof_rate=dof,
        chi2_tau=float(np.sum(ch.white_tau(tau_res) ** 2)),
        J=J,
        r_white=state.r_white,
        converged=converged,
        corr=corr,
        n_rate_params=n_rate_params,
    )


def _covariance(J: np.ndarray) -> np.ndarray:
    """(J^T J)^-1 of a whitened Jacobian, column-scaled for conditioning."""
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms
    return np.linalg.pinv(Js.T @ Js, rcond=1e-13) / np.outer(norms, norms)
