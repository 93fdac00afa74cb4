"""The gap measured on data the fit did not see.

Held-out units are points, each with all its rows (its rate, its period
identity and its grating harmonics); static points are held out too, since the
twin predicts every static rate (one bias k0, no free level per position).
Three schemes: leave one position out, leave one frequency out (static points
are a "frequency" of their own), leave one block of the run order out (BLOCKS
contiguous blocks of points).

For a fitted model with whitened Jacobian J and residual r (station.gap.fit), each
fold is the model linearised at the full-data estimate refitted on the
training rows (one Gauss-Newton step: exact for k0 and K, and for effects that
are linear in their parameters), in closed form from one QR factorisation
J = Q R of all rows: with H_gg = Q_g Q_g^T the hat matrix of the held-out rows
g, the held-out residual is e_(-g) = (I - H_gg)^-1 r_g and its predictive
covariance (I - H_gg)^-1 = I + J_g (J_T^T J_T)^-1 J_g^T (Woodbury), so
z_i^2 = e_(-g),i^2 / [(I - H_gg)^-1]_ii: a standardisation by the predictive
variance sigma_i^2 + x_i^T Cov x_i with sigma_i the honest noise (station.gap.noise).
The cost is one factorisation plus a |g| x |g| solve per fold: linear in points.

Metric: G = mean over held-out rows of z^2, minus 1 (0 when the model is
right; averaged over the three schemes). In rate units: the excess RMS
sqrt(max(0, mean(e^2 - var))) of the held-out rates, referred to a window of
T_ref seconds (rad/s); in timing units the same for the period identities (s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.gap.design import PointDesign
from station.gap.rawstreams import ROWS_PER_RECORD

BLOCKS = 4
# A direction of the model that the training rows of a fold carry less than this fraction of (the rest is in
# the held-out rows) is predicted with a variance over 1e6 times the noise's: such a prediction tests nothing
# (8 index harmonics on 10 equal-angle positions: a position left out is all that fixes some of them), and its
# z^2 is dominated by rounding and the linearisation's remainder amplified 1 / lambda times.
UNPREDICTABLE_EIG = 1e-6


@dataclass(frozen=True)
class Folds:
    """Held-out point sets of each scheme (indices into the points)."""

    schemes: dict[str, list[np.ndarray]]

    @classmethod
    def of(cls, design: PointDesign) -> Folds:
        pts = np.arange(design.n_points)
        schemes: dict[str, list[np.ndarray]] = {}
        pos = [pts[design.pos_index == j] for j in np.unique(design.pos_index)]
        if len(pos) >= 2:
            schemes["leave_position_out"] = pos
        freqs = np.unique(design.freq_hz)
        if freqs.size >= 2:
            schemes["leave_frequency_out"] = [pts[design.freq_hz == f] for f in freqs]
        if pts.size >= 2 * BLOCKS:
            order = pts[np.argsort(design.sequence, kind="stable")]
            schemes["leave_time_block_out"] = [b for b in np.array_split(order, BLOCKS) if b.size]
        return cls(schemes)


@dataclass(frozen=True)
class HeldOut:
    """Held-out gap of one model."""

    G: float  # mean z^2 - 1 over the schemes
    by_scheme: dict[str, float]
    by_channel: dict[str, float]  # rate rows and period-identity rows, every scheme together
    se: float  # standard error of G under a right model (chi-square_1 rows)
    rate_excess_rms_radps: float
    timing_excess_rms_s: float
    n_rows: int

    def to_json(self) -> dict:
        return {
            "metric": "held-out mean z^2 - 1, z = held-out residual / sqrt(sigma^2 + x^T Cov x), "
            "averaged over the schemes (0 when the model is right)",
            "value": _r(self.G),
            "standard_error_if_no_gap": _r(self.se),
            "by_scheme": {k: _r(v) for k, v in self.by_scheme.items()},
            "by_channel": {k: _r(v) for k, v in self.by_channel.items()},
            "rate_excess_rms_radps": _r(self.rate_excess_rms_radps),
            "rate_units_note": "sqrt(max(0, mean(e^2 - predictive variance))) of held-out rates, "
            "referred to a window of T_ref (the twin's rate_noise_ref_s)",
            "timing_excess_rms_s": _r(self.timing_excess_rms_s),
            "n_heldout_rows": self.n_rows,
        }


def _r(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _predict_fold(Q: np.ndarray, rw: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Held-out z^2 of `rows` and their leverage h (closed form from Q of all rows); NaN where unpredictable.

    (I - Q_g Q_g^T)^-1 = I + Q_g (I_p - Q_g^T Q_g)^-1 Q_g^T (Woodbury): p x p work, p the model's rank.
    A fold that takes away every row exciting some direction of the model (an eigenvalue of
    I_p - Q_g^T Q_g near 0) cannot predict the held-out rows that depend on it: those get NaN."""
    Qg = Q[rows]
    lam, V = np.linalg.eigh(np.eye(Qg.shape[1]) - Qg.T @ Qg)
    ok = lam > UNPREDICTABLE_EIG
    QV = Qg @ V
    QM = QV[:, ok] / lam[ok]
    e = rw[rows] + QM @ (QV[:, ok].T @ rw[rows])  # (I - H_gg)^-1 r_g
    v = 1.0 + np.sum(QM * QV[:, ok], axis=1)  # diag (I - H_gg)^-1 = 1 + x (J_T^T J_T)^-1 x^T
    z2 = e * e / v
    lost = np.sum(QV[:, ~ok] ** 2, axis=1) > UNPREDICTABLE_EIG
    z2[lost] = np.nan
    return z2, v - 1.0


def _nanmean(x: np.ndarray) -> float:
    """Mean over the predictable rows (NaN if there is none)."""
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else math.nan


def _orthonormal(J: np.ndarray) -> np.ndarray:
    """Orthonormal basis of J's column space (column-scaled, rank-revealing)."""
    J = J[:, np.linalg.norm(J, axis=0) > 0]
    U, s, _ = np.linalg.svd(J / np.linalg.norm(J, axis=0), full_matrices=False)
    return U[:, s > 1e-10 * s.max()] if s.size else U


def heldout(
    J: np.ndarray,
    r: np.ndarray,
    design: PointDesign,
    folds: Folds,
    rate_sigma_ratio: float,
    sigma0_radps: float,
    sigma_tau_s: float,
    grating_index: np.ndarray | None = None,
) -> HeldOut:
    """Held-out gap of the model with whitened Jacobian J and residual r (rate, timing, then grating rows).

    rate_sigma_ratio = honest sigma0 / the sigma0 that whitened J and r: the rate
    rows are re-whitened by the honest noise before anything else. grating_index:
    the points with grating rows (ROWS_PER_RECORD each, in that order).
    """
    n = design.n_points
    vib_idx = np.flatnonzero(design.vib)
    n_tau = vib_idx.size
    tau_row = np.full(n, -1)
    tau_row[vib_idx] = n + np.arange(n_tau)
    g_rows: dict[int, np.ndarray] = {}
    if grating_index is not None:
        for m, i in enumerate(grating_index):
            g_rows[int(i)] = n + n_tau + ROWS_PER_RECORD * m + np.arange(ROWS_PER_RECORD)
    Jw, rw = J.copy(), r.copy()
    Jw[:n] /= rate_sigma_ratio
    rw[:n] /= rate_sigma_ratio
    Q = _orthonormal(Jw)
    by_scheme: dict[str, float] = {}
    z2_rate, z2_tau, z2_g, ex_rate, ex_tau = [], [], [], [], []
    for scheme, fold_list in folds.schemes.items():
        z2_scheme = []
        for held in fold_list:
            t_rows = tau_row[held][tau_row[held] >= 0]
            gr = [g_rows[int(i)] for i in held if int(i) in g_rows]
            rows = np.concatenate([held, t_rows, *gr]).astype(int)
            z2, h = _predict_fold(Q, rw, rows)
            k, kt = held.size, t_rows.size
            z2_scheme.append(z2)
            z2_rate.append(z2[:k])
            z2_tau.append(z2[k : k + kt])
            z2_g.append(z2[k + kt :])
            # Back to physical units: rate rows referred to T_ref, timing rows in seconds.
            ex_rate.append((z2[:k] - 1.0) * (1.0 + h[:k]) * sigma0_radps**2)
            ex_tau.append((z2[k : k + kt] - 1.0) * (1.0 + h[k : k + kt]) * sigma_tau_s**2)
        by_scheme[scheme] = float(_nanmean(np.concatenate(z2_scheme)) - 1.0)
    if not by_scheme:
        return HeldOut(math.nan, {}, {}, math.nan, math.nan, math.nan, 0)
    by_channel = {
        "rate": float(_nanmean(np.concatenate(z2_rate)) - 1.0),
        "timing": float(_nanmean(np.concatenate(z2_tau)) - 1.0) if n_tau else math.nan,
    }
    if g_rows:
        by_channel["grating"] = float(_nanmean(np.concatenate(z2_g)) - 1.0)
    rows_per_scheme = n + n_tau + ROWS_PER_RECORD * len(g_rows)
    return HeldOut(
        G=float(np.mean(list(by_scheme.values()))),
        by_scheme=by_scheme,
        by_channel=by_channel,
        se=math.sqrt(2.0 / rows_per_scheme),
        rate_excess_rms_radps=math.sqrt(max(0.0, float(_nanmean(np.concatenate(ex_rate))))),
        timing_excess_rms_s=math.sqrt(max(0.0, float(_nanmean(np.concatenate(ex_tau))))) if n_tau else math.nan,
        n_rows=int(sum(np.count_nonzero(np.isfinite(z)) for z in z2_rate + z2_tau + z2_g)),
    )


def shrink(before: HeldOut, after: HeldOut) -> float | None:
    """Fraction of the held-out gap that a model removes (1 = all of it); None without a gap (G < 2 se)."""
    if not math.isfinite(before.G) or 2.0 * before.se > before.G:
        return None
    return float((before.G - after.G) / before.G)
