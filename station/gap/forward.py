"""Exact forward model of a recorded session under a twin configuration (physics.md).

Every recorded point is predicted by its window-mean rate wbar = phi(Tm) / Tm
(physics.md, "Output measurement"): the twin's rate over one crank turn
(`periodic_rate`) integrated in closed form by `PrecessionWindow` from the
crank phase at the opening, gamma0 = -w_true (t1 - delta), to the recorded Tm,
with w_true = 2 pi f_cmd (1 + eps_f) and delta the read-head latency. A static
point is the rate at rest, c0 of `periodic_rate(theta, 0)`. Bias drift adds
the window mean of d t_session.

The model is linear in the instrument coefficients, so it is returned as a
base (k0 and every calibrated coefficient zero; earth rate and effects kept)
plus one unit column per calibrated coefficient; the fit (station.gap.fit) takes the
bias k0 and the coefficients from there by linear least squares. Every column
is the absolute window mean, static points included: the static rate of a
position is what the twin predicts there (k0 + kz c + kzz c^2 + ky (1 - c^2) +
k3 c^3 - earth rate, with index and mount angle errors in c; seed 003), never a
free level that would absorb an angle error's static signature.

A second observable comes from the timing capture itself: the period identity
tau = t2 - t1 + Tm - Np T_cmd is Np (T_true - T_cmd), i.e. 0 for a perfect
frequency (physics.md, "integer-period timing capture").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from station.gap.design import PointDesign
from station.twin.config import TwinConfig
from station.twin.effects import terms
from station.twin.inputs import instrument_inputs, instrument_rate_radps, rate_from_inputs
from station.twin.precession import N_PHASES, fourier_series

CALIBRATED: tuple[str, ...] = ("kz", "kzz", "ky", "k3")


@dataclass(frozen=True)
class Prediction:
    """Predicted observables of every point for one twin configuration.

    rate = base + k0 + units @ K reproduces the twin's wbar for bias k0 and coefficients K
    (CALIBRATED order), static and vibration points alike.
    tau_s: predicted period identity of every vibration point (0 for static).
    """

    base_radps: np.ndarray
    units_radps: np.ndarray
    tau_s: np.ndarray


def base_config(cfg: TwinConfig) -> TwinConfig:
    """cfg with k0 and the calibrated coefficients zero (earth rate, effect terms kept)."""
    inst = replace(cfg.instrument, k0=0.0, **{c: 0.0 for c in CALIBRATED})
    return replace(cfg, instrument=inst)


def drift_mean_radps(d_radps2: float, start_s: np.ndarray, Tm_s: np.ndarray) -> np.ndarray:
    """Window mean of the bias drift d t_session: phi = d (t0 t + t^2 / 2) over [0, Tm], divided by Tm."""
    return d_radps2 * (np.asarray(start_s, dtype=float) + 0.5 * np.asarray(Tm_s, dtype=float))


def period_identity_s(design: PointDesign, cfg: TwinConfig) -> np.ndarray:
    """tau = Np (T_true - T_cmd), T_true = T_cmd / (1 + eps_f), for vibration points; 0 for static ones."""
    tau = np.zeros(design.n_points)
    v = design.vib
    eps = terms.frequency_offset(cfg.effects)
    tau[v] = design.Np[v] / design.freq_hz[v] * (1.0 / (1.0 + eps) - 1.0)
    return tau


def predict(design: PointDesign, cfg: TwinConfig) -> Prediction:
    """Base and unit columns of the window-mean rate of every point, and the period identity.

    The unit columns are the window means of aI, aI^2, aP^2, aI^3 (kz, kzz, ky, k3 = 1; physics.md
    regressors) under cfg's geometry; the base is the rate with k0 and K zero (earth rate, effect terms), from the
    same inputs (the coefficients do not enter them)."""
    base_cfg = base_config(cfg)

    def samples(theta: float, psi: np.ndarray, w: float) -> list[np.ndarray]:
        inputs = instrument_inputs(theta, psi, w, cfg)
        a_i, a_p = inputs[0], inputs[1]
        return [np.asarray(rate_from_inputs(inputs, base_cfg), dtype=float), a_i, a_i**2, a_p**2, a_i**3]

    means = _window_means(design, cfg, samples, 1 + len(CALIBRATED))
    base = means[:, 0] + drift_mean_radps(terms.bias_slope_radps2(cfg.effects), design.start_s, design.Tm_s)
    return Prediction(base, means[:, 1:], period_identity_s(design, cfg))


def predict_full(design: PointDesign, cfg: TwinConfig, coefficients: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Absolute window-mean rate of every point with calibrated coefficients K, and tau.

    One twin evaluation per point instead of five: what finite-difference columns
    need (k0 is the twin's; a difference of two predictions cancels it).
    """
    inst = replace(cfg.instrument, **dict(zip(CALIBRATED, map(float, coefficients), strict=True)))
    full = replace(cfg, instrument=inst)

    def samples(theta: float, psi: np.ndarray, w: float) -> list[np.ndarray]:
        return [np.asarray(instrument_rate_radps(theta, psi, w, full), dtype=float)]

    rate = _window_means(design, cfg, samples, 1)[:, 0]
    rate = rate + drift_mean_radps(terms.bias_slope_radps2(cfg.effects), design.start_s, design.Tm_s)
    return rate, period_identity_s(design, cfg)


def _vibration_means(series, key: np.ndarray, w_radps: np.ndarray, gamma0_rad: np.ndarray, Tm_s: np.ndarray):
    """phi(Tm) / Tm of every window (rows) for every output, each window on the series of its key.

    The closed form of station.twin.precession.PrecessionWindow.phi_rad (its module docstring), vectorised over
    windows and outputs: phi = c0 Tm + sum_k [alpha_k (sin k psi_T - sin k gamma0) + beta_k (cos k gamma0 -
    cos k psi_T)] / (k w), psi_T = w Tm + gamma0; the phases are shared by the outputs of a window."""
    c0, alpha, beta = series  # (keys, outputs), (keys, outputs, K)
    k = np.arange(1, alpha.shape[-1] + 1, dtype=float)
    kg = np.multiply.outer(gamma0_rad, k)
    kT = np.multiply.outer(w_radps * Tm_s + gamma0_rad, k)
    scale = 1.0 / np.multiply.outer(w_radps, k)
    s = (np.sin(kT) - np.sin(kg)) * scale
    c = (np.cos(kg) - np.cos(kT)) * scale
    per = np.einsum("ick,ik->ic", alpha[key], s) + np.einsum("ick,ik->ic", beta[key], c)
    return c0[key] + per / Tm_s[:, None]


def _window_means(design: PointDesign, cfg: TwinConfig, samples, n_out: int) -> np.ndarray:
    """Window means of every point (points x n_out) of the rates that samples(theta, psi, w) returns.

    Static points: the crank rests at psi = 0 (physics.md). Vibration points that share a position and
    frequency share one Fourier series per output (sampled once per position and frequency; the series of
    every case from one FFT, the window means of every point at once, _vibration_means); frequency and
    latency come from cfg: gamma0 = -w_true (t1 - delta), the read head stamps the crossing of psi = 0 delta
    late (physics.md).
    """
    out = np.empty((design.n_points, n_out))
    zero = np.zeros(1)
    position_rad = design.position_rad
    for j, theta in enumerate(position_rad):
        rows = samples(float(theta), zero, 0.0)
        at = (design.pos_index == j) & ~design.vib
        out[at] = [float(np.ravel(r)[0]) for r in rows]
    vib = np.flatnonzero(design.vib)
    if not vib.size:
        return out
    f_true = design.freq_hz[vib] * (1.0 + terms.frequency_offset(cfg.effects))
    latency_s = terms.reference_latency_s(cfg.effects)
    psi = 2.0 * np.pi * np.arange(N_PHASES) / N_PHASES
    keys, key = np.unique(np.column_stack([design.pos_index[vib], f_true]), axis=0, return_inverse=True)
    stacked = np.empty((len(keys), n_out, N_PHASES))
    for m, (j, f) in enumerate(keys):
        for c, r in enumerate(samples(float(position_rad[int(j)]), psi, 2.0 * math.pi * float(f))):
            stacked[m, c] = r  # broadcast over the phases where r is constant
    w = 2.0 * math.pi * f_true
    gamma0 = -w * (design.t1_s[vib] - latency_s)
    out[vib] = _vibration_means(fourier_series(stacked), np.ravel(key), w, gamma0, design.Tm_s[vib])
    return out
