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
plus one unit column per calibrated coefficient; the fit (gap.fit) takes the
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

from gap.design import PointDesign
from models.config import InstrumentCoefficients, TwinConfig
from models.precession import PrecessionWindow, periodic_rate

CALIBRATED: tuple[str, ...] = ("kz", "kzz", "ky", "k3")
# Effects whose only action is an instrument term: dropped from the unit-coefficient configs.
_INSTRUMENT_TERM_EFFECTS = ("odd_quadratic", "cross_coupling", "lateral_resonance")


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


def unit_config(cfg: TwinConfig, coefficient: str) -> TwinConfig:
    """cfg with one calibrated coefficient = 1, every other rate term zero (geometry kept)."""
    effects = {k: v for k, v in cfg.effects.items() if k not in _INSTRUMENT_TERM_EFFECTS}
    zero = InstrumentCoefficients(k0=0.0, kz=0.0, kzz=0.0, ky=0.0, k3=0.0)
    return replace(cfg, instrument=replace(zero, **{coefficient: 1.0}), effects=effects, earth_rate_on=False)


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
    eps = cfg.param("frequency_error", "eps_f")
    tau[v] = design.Np[v] / design.freq_hz[v] * (1.0 / (1.0 + eps) - 1.0)
    return tau


def predict(design: PointDesign, cfg: TwinConfig) -> Prediction:
    """Base and unit columns of the window-mean rate of every point, and the period identity."""
    means = _window_means(design, cfg, [base_config(cfg)] + [unit_config(cfg, c) for c in CALIBRATED])
    base = means[:, 0] + drift_mean_radps(cfg.param("bias_drift", "d"), design.start_s, design.Tm_s)
    return Prediction(base, means[:, 1:], period_identity_s(design, cfg))


def predict_full(design: PointDesign, cfg: TwinConfig, coefficients: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Absolute window-mean rate of every point with calibrated coefficients K, and tau.

    One twin evaluation per point instead of five: what finite-difference columns
    need (k0 is the twin's; a difference of two predictions cancels it).
    """
    inst = replace(cfg.instrument, **dict(zip(CALIBRATED, map(float, coefficients), strict=True)))
    rate = _window_means(design, cfg, [replace(cfg, instrument=inst)])[:, 0]
    rate = rate + drift_mean_radps(cfg.param("bias_drift", "d"), design.start_s, design.Tm_s)
    return rate, period_identity_s(design, cfg)


def _static_levels(design: PointDesign, configs: list[TwinConfig]) -> np.ndarray:
    """Static rate at each point's position under each config (points x configs)."""
    per_position = np.array([[periodic_rate(th, 0.0, c).c0_radps for c in configs] for th in design.position_rad])
    return per_position[design.pos_index]


def _rates_by_case(design: PointDesign, f_true: np.ndarray, configs: list[TwinConfig]) -> dict:
    """periodic_rate of each distinct (position, true frequency) of the vibration points, per config.

    Points that share a position and frequency share the rate's Fourier series (the costly part);
    only the window's phase and length differ."""
    out: dict[tuple[int, float], list] = {}
    for i in np.flatnonzero(design.vib):
        key = (int(design.pos_index[i]), float(f_true[i]))
        if key not in out:
            theta = float(design.position_rad[key[0]])
            out[key] = [periodic_rate(theta, key[1], c) for c in configs]
    return out


def _window_means(design: PointDesign, cfg: TwinConfig, configs: list[TwinConfig]) -> np.ndarray:
    """Window-mean rate of every point under each config (points x configs), frequency and latency from cfg.

    gamma0 = -w_true (t1 - delta): the read head stamps the crossing of psi = 0 delta late (physics.md).
    """
    f_true = design.freq_hz * (1.0 + cfg.param("frequency_error", "eps_f"))
    latency_s = cfg.param("readhead_latency", "delta")
    out = _static_levels(design, configs)
    rates = _rates_by_case(design, f_true, configs)
    for i in np.flatnonzero(design.vib):
        w = 2.0 * math.pi * f_true[i]
        gamma0 = -w * (design.t1_s[i] - latency_s)
        per_config = rates[(int(design.pos_index[i]), float(f_true[i]))]
        out[i] = [float(PrecessionWindow(r, w, gamma0).phi_rad(design.Tm_s[i])) / design.Tm_s[i] for r in per_config]
    return out
