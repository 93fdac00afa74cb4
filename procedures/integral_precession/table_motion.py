"""The table's motion from the grating record and the reference crossings (seed 000 6.1.1, eqs. 30-32, Table 5).

The crank phase of every sample comes from the reference crossings (psi = 0 mod 2 pi,
physics.md): a straight line t_k = t0 + k T through the crossing times gives the crank's
mean period T (the measured frequency, not the commanded one) and psi(t) = 2 pi (t - t0) / T.

The harmonics of z(t) relative to psi (eq. 30) are fitted by least squares on
1, sin j psi, cos j psi. The seed calls this harmonic analysis an FFT; a raw FFT of the
5 kHz record would need a whole number of periods on the sample grid (3 Hz gives
1666.67 samples a period, and a stretch never starts on a crossing), leaks between bins
otherwise, and gives phases relative to the first sample instead of psi = 0. The least
squares has none of those limits, equals the FFT's Fourier coefficients when the record
does hold whole periods on the grid, and gives each coefficient's uncertainty from the
fit residuals.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from station.constants import GRATING_RATE_HZ, TIMER_TICK_S
from station.errors import InputError

TWO_PI = 2.0 * math.pi

# Seed 000 Table 5 (mm in the seed, metres here): frequency (Hz) -> (Zs1, dA_max, Zs2, Zc2).
SEED_TABLE5_M = {
    1.0: (-0.0886e-3, 2.37e-8, 0.0024e-3, -0.0042e-3),
    3.0: (-0.0774e-3, 0.0002e-3, 0.0004e-3, -0.0207e-3),
    5.0: (-0.0548e-3, 0.0006e-3, -0.0030e-3, 0.0043e-3),
    7.0: (-0.0048e-3, 0.0012e-3, -0.0019e-3, -0.0141e-3),
    9.0: (0.0504e-3, 0.0019e-3, -0.0014e-3, 0.0475e-3),
    10.0: (0.0834e-3, 0.0024e-3, 0.0021e-3, -0.0024e-3),
}
SEED_Z0_M, SEED_Z1_M_S_PER_RAD = -1.299e-4, 3.2e-6  # seed 000 eq. 32 (-0.1299 mm + 0.0032 mm s/rad w)


class MotionFitError(InputError):
    """The record cannot give what was asked (too few crossings or samples)."""


@dataclass(frozen=True)
class CrankPhase:
    """psi(t) = 2 pi (t - t0) / T from the reference crossings' line fit."""

    t0_s: float  # the fitted crossing nearest the middle of the crossings
    period_s: float
    cov: np.ndarray  # 2 x 2 covariance of (t0_s, period_s)
    n_crossings: int

    @property
    def freq_hz(self) -> float:
        return 1.0 / self.period_s

    @property
    def sigma_freq_hz(self) -> float:
        return math.sqrt(self.cov[1, 1]) / self.period_s**2

    def psi_rad(self, t_s: np.ndarray) -> np.ndarray:
        return TWO_PI * (np.asarray(t_s, dtype=float) - self.t0_s) / self.period_s


def crank_phase(crossings_s: np.ndarray, period_hint_s: float, tick_s: float = TIMER_TICK_S) -> CrankPhase:
    """Least-squares line t_k = t0 + k T through the crossing times (psi = 2 pi k).

    `period_hint_s` (the commanded period) numbers the crossings, so that stretches of
    crossings far apart, or a missed crossing, still give one straight line. The time
    stamps' scatter is the fit's residual, and at least that of the timer's quantisation;
    when the period is a whole number of ticks every crossing is rounded alike, so the
    quantisation (tick^2 / 12) also stands in t0 as a common offset that no fit averages out.
    """
    t = np.sort(np.asarray(crossings_s, dtype=float))
    if t.size < 2:
        raise MotionFitError(f"{t.size} reference crossing(s): the crank phase needs at least 2")
    k = np.rint((t - t[0]) / period_hint_s)
    if np.any(np.diff(k) < 1):
        raise MotionFitError(f"reference crossings closer than a period of {period_hint_s:g} s: not one crank")
    k -= k[np.argmin(np.abs(k - k.mean()))]
    X = np.column_stack([np.ones_like(k), k])
    beta, *_ = np.linalg.lstsq(X, t, rcond=None)
    resid = t - X @ beta
    dof = t.size - 2
    scatter = math.sqrt(float(resid @ resid) / dof) if dof > 0 else 0.0
    sigma_t = max(scatter, tick_s / math.sqrt(12.0))
    cov = sigma_t**2 * np.linalg.inv(X.T @ X) + np.diag([tick_s**2 / 12.0, 0.0])
    return CrankPhase(float(beta[0]), float(beta[1]), cov, int(t.size))


@dataclass(frozen=True)
class FourierFit:
    """y = c0 + sum_j (s_j sin j psi + c_j cos j psi), j = 1..n, by least squares."""

    coef: np.ndarray  # (c0, s_1, c_1, s_2, c_2, ...)
    cov: np.ndarray
    residual_rms: float
    dof: int

    @property
    def mean(self) -> float:
        return float(self.coef[0])

    @property
    def sin(self) -> np.ndarray:
        return self.coef[1::2]

    @property
    def cos(self) -> np.ndarray:
        return self.coef[2::2]

    @property
    def sigma_mean(self) -> float:
        return math.sqrt(self.cov[0, 0])

    @property
    def sigma_sin(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov)[1::2])

    @property
    def sigma_cos(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov)[2::2])


def fourier_fit(psi_rad: np.ndarray, y: np.ndarray, n_harmonics: int) -> FourierFit:
    """Least squares on 1, sin j psi, cos j psi; covariance sigma^2 (X^T X)^-1 from the residuals."""
    psi = np.asarray(psi_rad, dtype=float)
    y = np.asarray(y, dtype=float)
    cols = [np.ones_like(psi)]
    for j in range(1, n_harmonics + 1):
        cols += [np.sin(j * psi), np.cos(j * psi)]
    X = np.column_stack(cols)
    n, p = X.shape
    if n <= p:
        raise MotionFitError(f"{n} samples cannot fit {p} Fourier coefficients")
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ beta
    dof = n - p
    rms = math.sqrt(float(resid @ resid) / dof)
    return FourierFit(beta, rms**2 * np.linalg.inv(X.T @ X), rms, dof)


def phased_fourier_fit(t_s: np.ndarray, y: np.ndarray, phase: CrankPhase, n_harmonics: int) -> FourierFit:
    """fourier_fit at psi(t) from the crossings, its covariance including that of the phase itself.

    An error in t0 turns every harmonic, an error in T makes the phase drift along the
    record; both are propagated to first order (J cov(t0, T) J^T, J by central
    differences of one standard uncertainty).
    """
    t = np.asarray(t_s, dtype=float)
    fit = fourier_fit(phase.psi_rad(t), y, n_harmonics)
    jac = []
    for i in range(2):
        h = math.sqrt(phase.cov[i, i])
        coefs = []
        for sign in (1.0, -1.0):
            t0, period = phase.t0_s + sign * h * (i == 0), phase.period_s + sign * h * (i == 1)
            coefs.append(fourier_fit(TWO_PI * (t - t0) / period, y, n_harmonics).coef)
        jac.append((coefs[0] - coefs[1]) / (2 * h))
    J = np.column_stack(jac)
    return FourierFit(fit.coef, fit.cov + J @ phase.cov @ J.T, fit.residual_rms, fit.dof)


@dataclass(frozen=True)
class Waveform:
    """Eq. 30 at one frequency: A_s, Zsj, Zcj (j = 1..n, Zs1 without A0) and their uncertainties, in metres."""

    freq_hz: float  # measured from the crossings
    sigma_freq_hz: float
    mean_m: float  # A_s
    sigma_mean_m: float
    zs_m: np.ndarray
    zc_m: np.ndarray
    sigma_zs_m: np.ndarray
    sigma_zc_m: np.ndarray
    residual_rms_m: float
    n_samples: int
    n_crossings: int

    @property
    def w_radps(self) -> float:
        return TWO_PI * self.freq_hz


def waveform(t_s: np.ndarray, z_m: np.ndarray, crossings_s: np.ndarray, a0_m: float, period_hint_s: float,
             n_harmonics: int = 3) -> Waveform:  # fmt: skip
    """Harmonics of a grating stretch relative to the crank phase (seed 000 eq. 30)."""
    phase = crank_phase(crossings_s, period_hint_s)
    fit = phased_fourier_fit(t_s, z_m, phase, n_harmonics)
    zs = fit.sin.copy()
    zs[0] -= a0_m
    return Waveform(phase.freq_hz, phase.sigma_freq_hz, fit.mean, fit.sigma_mean, zs, fit.cos.copy(), fit.sigma_sin,
                    fit.sigma_cos, fit.residual_rms, int(np.size(t_s)), phase.n_crossings)  # fmt: skip


def sampling_delay_error_m(freq_hz, a0_m: float, rate_hz: float = GRATING_RATE_HZ):
    """Eq. 31: dA_max = A0 sin(pi/2) - A0 sin(pi/2 + 2 pi f / rate), the amplitude missed by one sample's delay."""
    return a0_m * (1.0 - np.cos(TWO_PI * np.asarray(freq_hz, dtype=float) / rate_hz))


@dataclass(frozen=True)
class Zs1Line:
    """Eq. 32: Zs1(w) = z0 + z1 w, by weighted least squares."""

    z0_m: float
    z1_m_s_per_rad: float
    cov: np.ndarray  # of (z0, z1), scaled by chi2/dof when that exceeds 1
    chi2: float
    dof: int

    @property
    def sigma_z0_m(self) -> float:
        return math.sqrt(self.cov[0, 0])

    @property
    def sigma_z1_m_s_per_rad(self) -> float:
        return math.sqrt(self.cov[1, 1])

    def zs1_m(self, w_radps: float) -> float:
        return self.z0_m + self.z1_m_s_per_rad * w_radps


def fit_zs1(
    w_radps: Sequence[float] | np.ndarray, zs1_m: Sequence[float] | np.ndarray, sigma_m: Sequence[float] | np.ndarray
) -> Zs1Line:
    """Weighted straight line through Zs1(w) (seed 000 eq. 32).

    The covariance is that of the stated sigmas, inflated by chi2/dof (the Birge ratio
    squared) when the points scatter about the line more than their sigmas allow: a real
    table's Zs1 is not exactly linear in w (Table 5), and z0, z1 must not claim more.
    """
    w = np.asarray(w_radps, dtype=float)
    z = np.asarray(zs1_m, dtype=float)
    s = np.asarray(sigma_m, dtype=float)
    if w.size < 2 or np.unique(w).size < 2:
        raise MotionFitError(f"Zs1(w) needs at least two frequencies, got {np.unique(w).size}")
    if np.any(~(s > 0)):
        raise MotionFitError("every Zs1 needs a positive uncertainty for the weighted fit")
    X = np.column_stack([np.ones_like(w), w]) / s[:, None]
    beta, *_ = np.linalg.lstsq(X, z / s, rcond=None)
    resid = z / s - X @ beta
    chi2 = float(resid @ resid)
    dof = w.size - 2
    cov = np.linalg.inv(X.T @ X) * (max(1.0, chi2 / dof) if dof > 0 else 1.0)
    return Zs1Line(float(beta[0]), float(beta[1]), cov, chi2, dof)
