"""Vibration frequency stability and accuracy (seed 000 6.1.2, eq. 33, Table 6).

At each nominal frequency f the reference mark monitor times consecutive periods;
fbar is the mean of their frequencies f_e and sigma_f / f = (1 / (sqrt(N - 1) fbar))
sqrt(sum (f_e - fbar)^2), the seed's 1/3 for N = 10 (drivers.reference_marks.driver).
Table 6 gives fbar, Delta f = f - fbar and sigma_f / f; eq. 33 the error of the
instrument's mean rate that a frequency 3 sigma_f off nominal leaves in 10 periods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station import constants
from station.constants import TIMER_TICK_S


def mean_rate_error_radps(freq_hz, sigma_f_hz, a0_m: float, kz_radps_per_g: float, g_mps2: float, periods: int = 10):
    """Eq. 33: the kz term's mean over `periods` nominal periods when the table runs at f + 3 sigma_f.

    Delta alpha = (f / P) int_0^{P/f} kz a_z(t) / g dt with a_z = -A0 (2 pi fe)^2 sin(2 pi fe t),
    fe = f + 3 sigma_f, P = 10:  A0 2 pi f fe (cos(2 pi P fe / f) - 1) kz / (P g).
    The seed prints it without the 1/g (kz is per g, A0 w^2 in m/s^2) and with the
    integrand's sign dropped; the closed form here is the integral's.
    """
    f = np.asarray(freq_hz, dtype=float)
    fe = f + 3.0 * np.asarray(sigma_f_hz, dtype=float)
    slip = np.cos(2 * np.pi * periods * fe / f) - 1.0
    return a0_m * 2 * np.pi * f * fe * slip * kz_radps_per_g / (periods * g_mps2)


def sigma_mean_freq_hz(fbar_hz: float, stability: float, periods: int, tick_s: float = TIMER_TICK_S) -> float:
    """Standard uncertainty of fbar: the periods' scatter sigma_f / sqrt(N), and at least the timer's resolution.

    The mean of N consecutive periods depends only on the first and last time stamps,
    each rounded to a tick (variance tick^2 / 12): sigma(fbar) / fbar >= fbar tick / (N sqrt 6).
    """
    scatter = stability * fbar_hz / math.sqrt(periods)
    quantised = fbar_hz**2 * tick_s / (periods * math.sqrt(6.0))
    return math.hypot(scatter, quantised)


@dataclass(frozen=True)
class Table6Row:
    """One column of seed 000 Table 6."""

    commanded_hz: float
    fbar_hz: float
    sigma_fbar_hz: float
    stability: float  # sigma_f / f
    periods: int
    delta_alpha_radps: float  # eq. 33

    @property
    def delta_f_hz(self) -> float:
        """Delta f = f - fbar (the seed's sign: positive when the table runs slow)."""
        return self.commanded_hz - self.fbar_hz

    @property
    def eps_f(self) -> float:
        """The relative frequency error fbar / f - 1 (the twin's frequency_error eps_f)."""
        return self.fbar_hz / self.commanded_hz - 1.0

    def passes(self, stability_max: float = constants.FREQ_STABILITY_MAX) -> bool:
        return self.stability < stability_max


def table6_row(commanded_hz: float, fbar_hz: float, stability: float, periods: int, *, a0_m: float,
               kz_radps_per_g: float, g_mps2: float) -> Table6Row:  # fmt: skip
    sigma_f = stability * fbar_hz
    return Table6Row(commanded_hz, fbar_hz, sigma_mean_freq_hz(fbar_hz, stability, periods), stability, periods,
                     float(mean_rate_error_radps(commanded_hz, sigma_f, a0_m, kz_radps_per_g, g_mps2)))  # fmt: skip


def mean_eps_f(rows: list[Table6Row]) -> tuple[float, float, float]:
    """Weighted mean of eps_f over the frequencies: (eps_f, its sigma, chi2 per degree of freedom).

    One eps_f for the whole range is what the twin's frequency_error assumes; chi2/dof
    far above 1 says the error is not proportional to f. The sigma is inflated by
    sqrt(chi2/dof) when that exceeds 1.
    """
    eps = np.array([r.eps_f for r in rows])
    sig = np.array([r.sigma_fbar_hz / r.commanded_hz for r in rows])
    w = 1.0 / sig**2
    mean = float(np.sum(w * eps) / np.sum(w))
    chi2_dof = float(np.sum(w * (eps - mean) ** 2) / (eps.size - 1)) if eps.size > 1 else 0.0
    return mean, math.sqrt(1.0 / float(np.sum(w)) * max(1.0, chi2_dof)), chi2_dof
