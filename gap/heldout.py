"""The gap measured on data the fit did not see.

Held-out units are vibration points (their rate and their period identity);
static points always stay in the training set, since with one free static
level per position a held-out static point could not be predicted at all.
Three schemes: leave one position out, leave one frequency out, leave one
block of the run order out (BLOCKS contiguous blocks of vibration points).

For a fitted model with whitened Jacobian J and residual r (gap.fit),
each fold refits the model linearised at the full-data estimate on the
training rows (one Gauss-Newton step: exact for the static levels and K,
and for effects that are linear in their parameters) and predicts the
held-out rows. A held-out residual is standardised by its predictive
variance, z^2 = e^2 / (sigma_i^2 + x_i^T Cov x_i), with sigma_i the honest
noise (gap.noise): in whitened units z^2 = e^2 / (1 + h_i),
h_i = x_i^T (J_T^T J_T)^-1 x_i.

Metric: G = mean over held-out rows of z^2, minus 1 (0 when the model is
right; averaged over the three schemes). In rate units: the excess RMS
sqrt(max(0, mean(e^2 - var))) of the held-out rates, referred to a window of
T_ref seconds (rad/s); in timing units the same for the period identities (s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gap.design import PointDesign

BLOCKS = 4


@dataclass(frozen=True)
class Folds:
    """Held-out vibration-point sets of each scheme (indices into the points)."""

    schemes: dict[str, list[np.ndarray]]

    @classmethod
    def of(cls, design: PointDesign) -> Folds:
        vib = np.flatnonzero(design.vib)
        schemes: dict[str, list[np.ndarray]] = {}
        pos = [vib[design.pos_index[vib] == j] for j in np.unique(design.pos_index[vib])]
        if len(pos) >= 2:
            schemes["leave_position_out"] = pos
        freqs = np.unique(design.freq_hz[vib])
        if freqs.size >= 2:
            schemes["leave_frequency_out"] = [vib[design.freq_hz[vib] == f] for f in freqs]
        if vib.size >= 2 * BLOCKS:
            order = vib[np.argsort(design.sequence[vib], kind="stable")]
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


def _predict_fold(Jw: np.ndarray, rw: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Refit on every row but `rows` (one Gauss-Newton step) and return the held-out z^2 and leverage h."""
    train = np.ones(rw.size, dtype=bool)
    train[rows] = False
    JT = Jw[train]
    keep = np.linalg.norm(JT, axis=0) > 0
    JT, JH = JT[:, keep], Jw[rows][:, keep]
    pinv = np.linalg.pinv(JT, rcond=1e-11)
    e = rw[rows] - JH @ (pinv @ rw[train])
    h = np.sum((JH @ pinv) ** 2, axis=1)  # x (J^T J)^-1 x^T
    return e * e / (1.0 + h), h


def heldout(
    J: np.ndarray,
    r: np.ndarray,
    design: PointDesign,
    folds: Folds,
    rate_sigma_ratio: float,
    sigma0_radps: float,
    sigma_tau_s: float,
) -> HeldOut:
    """Held-out gap of the model with whitened Jacobian J and residual r.

    rate_sigma_ratio = honest sigma0 / the sigma0 that whitened J and r: the rate
    rows are re-whitened by the honest noise before anything else.
    """
    n = design.n_points
    vib_idx = np.flatnonzero(design.vib)
    tau_row = np.full(n, -1)
    tau_row[vib_idx] = n + np.arange(vib_idx.size)
    Jw, rw = J.copy(), r.copy()
    Jw[:n] /= rate_sigma_ratio
    rw[:n] /= rate_sigma_ratio
    by_scheme: dict[str, float] = {}
    z2_rate, z2_tau, ex_rate, ex_tau = [], [], [], []
    for scheme, fold_list in folds.schemes.items():
        z2_scheme = []
        for held in fold_list:
            z2, h = _predict_fold(Jw, rw, np.concatenate([held, tau_row[held]]))
            k = held.size
            z2_scheme.append(z2)
            z2_rate.append(z2[:k])
            z2_tau.append(z2[k:])
            # Back to physical units: rate rows referred to T_ref, timing rows in seconds.
            ex_rate.append((z2[:k] - 1.0) * (1.0 + h[:k]) * sigma0_radps**2)
            ex_tau.append((z2[k:] - 1.0) * (1.0 + h[k:]) * sigma_tau_s**2)
        by_scheme[scheme] = float(np.mean(np.concatenate(z2_scheme)) - 1.0)
    if not by_scheme:
        return HeldOut(math.nan, {}, {}, math.nan, math.nan, math.nan, 0)
    return HeldOut(
        G=float(np.mean(list(by_scheme.values()))),
        by_scheme=by_scheme,
        by_channel={
            "rate": float(np.mean(np.concatenate(z2_rate)) - 1.0),
            "timing": float(np.mean(np.concatenate(z2_tau)) - 1.0),
        },
        se=math.sqrt(2.0 / (2 * vib_idx.size)),
        rate_excess_rms_radps=math.sqrt(max(0.0, float(np.mean(np.concatenate(ex_rate))))),
        timing_excess_rms_s=math.sqrt(max(0.0, float(np.mean(np.concatenate(ex_tau))))),
        n_rows=int(sum(z.size for z in z2_rate + z2_tau)),
    )


def shrink(before: HeldOut, after: HeldOut) -> float | None:
    """Fraction of the held-out gap that a model removes (1 = all of it); None without a gap (G < 2 se)."""
    if not math.isfinite(before.G) or 2.0 * before.se > before.G:
        return None
    return float((before.G - after.G) / before.G)
