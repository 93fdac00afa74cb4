"""Precession angle phi(t) of one counter window in closed form, and its first passage Tm.

In steady vibration the rate w_out is a periodic function of the crank phase
psi = w t + gamma0 (physics.md). It is sampled on N = 256 phases and expanded
by FFT into r(psi) = c0 + sum_k (alpha_k cos k psi + beta_k sin k psi); for the
polynomial terms this is exact (degree <= 9 in e^{i psi}), and for
aI|aI| or cos(theta + alpha_x(psi)) the aliasing error is below 1e-12 of the
rate. The window's angle then integrates term by term:

    phi(t) = (c0 + e) t + sum_k [alpha_k (sin k psi - sin k gamma0) + beta_k (cos k gamma0 - cos k psi)] / (k w)
             + d (t0 t + t^2 / 2)

with e the window's rate-noise offset and d the bias drift (window opened at
session time t0). Tm is the first t > 0 with |phi(t)| = target (physics.md):
|phi| departs from the mean line by at most B = sum_k (|alpha_k| + |beta_k|) 2 / (k w),
so the root lies where the mean line is within B of the target; that band
(a few periods) is scanned, half a period at a time, on a grid of T/64 for the first sign change, each
grid cell in which the rate turns from rising to falling is checked at its
exact local maximum (so a crossing that touches the target between two grid
points is not missed), and the bracket is solved by Brent's method to 4 ulp
(relative 9e-16, far below the 1e-9 required), then polished by one Newton step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.optimize import brentq

from station.errors import StationFault
from station.twin.config import TwinConfig
from station.twin.inputs import instrument_rate_radps

N_PHASES = 256
_CELLS_PER_PERIOD = 64
_CHUNK_CELLS = _CELLS_PER_PERIOD // 2  # grid cells evaluated at once (crossings_s)
_RTOL = 4.0 * np.finfo(float).eps  # the smallest relative tolerance brentq accepts


class WindowNeverClosesError(StationFault):
    """The mean precession rate is too small (or reverses) for the window ever to close."""


def fourier_series(rate_at_phases: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """c0, alpha_k, beta_k (k = 1 .. N/2 - 1) of rates sampled at N equal crank phases (the last axis; many series
    at once): r = c0 + sum_k alpha_k cos k psi + beta_k sin k psi. A harmonic below 1e-17 |c0| (round-off of the
    FFT) is zero."""
    n = rate_at_phases.shape[-1]
    spectrum = np.fft.rfft(rate_at_phases, axis=-1) / n
    c0 = spectrum[..., 0].real
    coef = spectrum[..., 1 : n // 2]
    keep = np.abs(coef) > 1e-17 * np.maximum(np.abs(c0), 1e-30)[..., None]
    return c0, np.where(keep, 2.0 * coef.real, 0.0), np.where(keep, -2.0 * coef.imag, 0.0)


@dataclass(frozen=True)
class PeriodicRate:
    """r(psi) = c0 + sum_k (alpha_k cos k psi + beta_k sin k psi)."""

    c0_radps: float
    k: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray

    @classmethod
    def from_samples(cls, rate_at_phases: np.ndarray) -> PeriodicRate:
        c0, alpha, beta = fourier_series(rate_at_phases)
        keep = (alpha != 0.0) | (beta != 0.0)
        return cls(float(c0), np.arange(1, alpha.size + 1)[keep], alpha[keep], beta[keep])

    @classmethod
    def constant(cls, c0_radps: float) -> PeriodicRate:
        empty = np.zeros(0)
        return cls(float(c0_radps), empty.astype(int), empty, empty)


def periodic_rate(theta_rad: float, freq_hz: float, cfg: TwinConfig) -> PeriodicRate:
    """Fourier series of the rate over one crank turn at true frequency freq_hz (0 = static)."""
    if freq_hz == 0.0:
        # The crank rests at psi = 0 during a static test (physics.md).
        return PeriodicRate.constant(float(instrument_rate_radps(theta_rad, 0.0, 0.0, cfg)))
    psi = 2.0 * np.pi * np.arange(N_PHASES) / N_PHASES
    rate = instrument_rate_radps(theta_rad, psi, 2.0 * np.pi * freq_hz, cfg)
    return PeriodicRate.from_samples(np.asarray(rate, dtype=float))


@dataclass(frozen=True)
class PrecessionWindow:
    """phi(t) and w_out(t) of one window, t measured from the window's opening edge."""

    rate: PeriodicRate
    w_radps: float  # true angular frequency; 0 for a static window
    gamma0_rad: float  # crank phase at the window's opening
    offset_radps: float = 0.0  # window-mean rate noise
    drift_radps2: float = 0.0
    t0_session_s: float = 0.0

    @property
    def mean_rate_radps(self) -> float:
        return self.rate.c0_radps + self.offset_radps + self.drift_radps2 * self.t0_session_s

    def swing_bound_rad(self) -> float:
        """B >= |phi(t) - mean part| for all t."""
        if self.w_radps == 0.0 or self.rate.k.size == 0:
            return 0.0
        return float(np.sum((np.abs(self.rate.alpha) + np.abs(self.rate.beta)) * 2.0 / (self.rate.k * self.w_radps)))

    def _mean_angle(self, t):
        return self.mean_rate_radps * t + 0.5 * self.drift_radps2 * t * t

    @cached_property
    def _harmonics(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """k (as float), k w, sin k gamma0, cos k gamma0: what phi and the rate reuse at every t of the window."""
        kk = self.rate.k.astype(float)
        kg = kk * self.gamma0_rad
        return kk, kk * self.w_radps, np.sin(kg), np.cos(kg)

    def phi_rad(self, t):
        """Precession angle since the window opened (vectorised over t)."""
        t = np.asarray(t, dtype=float)
        out = self._mean_angle(t)
        if self.w_radps and self.rate.k.size:
            kk, kw, sin_kg, cos_kg = self._harmonics
            kpsi = np.multiply.outer(self.w_radps * t + self.gamma0_rad, kk)
            per = (self.rate.alpha * (np.sin(kpsi) - sin_kg) + self.rate.beta * (cos_kg - np.cos(kpsi))) / kw
            out = out + per.sum(axis=-1)
        return out

    def rate_radps(self, t):
        """w_out(t) including the noise offset and drift."""
        t = np.asarray(t, dtype=float)
        out = self.mean_rate_radps + self.drift_radps2 * t
        if self.w_radps and self.rate.k.size:
            kpsi = np.multiply.outer(self.w_radps * t + self.gamma0_rad, self._harmonics[0])
            out = out + (self.rate.alpha * np.cos(kpsi) + self.rate.beta * np.sin(kpsi)).sum(axis=-1)
        return out

    def _mean_time(self, level_rad: float, sign: float) -> float:
        """Smallest t >= 0 at which sign * mean angle reaches level (inf if never)."""
        if level_rad <= 0.0:
            return 0.0
        c = sign * self.mean_rate_radps
        d = sign * self.drift_radps2
        if d == 0.0:
            return level_rad / c if c > 0 else math.inf
        disc = c * c + 2.0 * d * level_rad
        if disc < 0:
            return math.inf
        root = math.sqrt(disc)
        # Numerically stable smaller positive root of d/2 t^2 + c t - level = 0.
        t = 2.0 * level_rad / (c + root) if c + root > 0 else math.inf
        return t if t >= 0 else math.inf

    def _bracket(self, target_rad: float) -> tuple[float, float, float]:
        sign = 1.0 if self.mean_rate_radps >= 0 else -1.0
        bound = self.swing_bound_rad()
        t_lo = self._mean_time(target_rad - bound, sign)
        t_hi = self._mean_time(target_rad + bound, sign)
        if not math.isfinite(t_hi):
            raise WindowNeverClosesError(
                f"mean precession rate {self.mean_rate_radps:.3e} rad/s never reaches {target_rad:.6g} rad"
            )
        return sign, t_lo, t_hi

    def crossings_s(self, target_rad: float, first_only: bool = True) -> list[float]:
        """Times t > 0 at which |phi(t)| = target, ascending; only the first by default."""
        sign, t_lo, t_hi = self._bracket(target_rad)

        def f(t: float) -> float:
            return sign * float(self.phi_rad(t)) - target_rad

        if self.w_radps == 0.0 or self.rate.k.size == 0:
            # No swing: the mean line (linear, or quadratic with drift) is the whole angle.
            return [self._polish(t_hi, f)]
        period = 2.0 * math.pi / abs(self.w_radps)
        n_cells = max(math.ceil((t_hi - t_lo) / period * _CELLS_PER_PERIOD), 8)
        grid = np.linspace(max(t_lo - period / _CELLS_PER_PERIOD, 0.0), t_hi + period / _CELLS_PER_PERIOD, n_cells + 3)
        roots: list[float] = []
        # _CHUNK_CELLS at a time, not the whole band (often several periods) at once: the first passage mostly lies in
        # its first chunks, and a grid point is the same elementwise computation in a chunk as in the whole grid
        for start in range(0, grid.size - 1, _CHUNK_CELLS):
            cells = grid[start : start + _CHUNK_CELLS + 1]
            fv = sign * self.phi_rad(cells) - target_rad
            rv = sign * self.rate_radps(cells)
            for i in range(cells.size - 1):
                a, b, fa, fb = cells[i], cells[i + 1], fv[i], fv[i + 1]
                brackets = []
                if rv[i] > 0 >= rv[i + 1] or rv[i] < 0 <= rv[i + 1]:
                    # An extremum inside the cell: split there so both roots are found.
                    tm = brentq(lambda t: sign * float(self.rate_radps(t)), a, b, xtol=1e-15)
                    fm = f(tm)
                    brackets = [(a, tm, fa, fm), (tm, b, fm, fb)]
                else:
                    brackets = [(a, b, fa, fb)]
                for ba, bb, fba, fbb in brackets:
                    if fba == 0.0 and ba > 0 and (not roots or roots[-1] != ba):
                        roots.append(float(ba))
                    elif (fba < 0.0 < fbb) or (fba > 0.0 > fbb):
                        roots.append(self._polish(brentq(f, ba, bb, xtol=1e-14, rtol=_RTOL, maxiter=200), f))
                    if first_only and roots:
                        return roots[:1]
        if not roots:
            raise WindowNeverClosesError(f"no passage of |phi| = {target_rad:.6g} rad found in [{t_lo}, {t_hi}] s")
        return roots

    def first_passage_s(self, target_rad: float) -> float:
        return self.crossings_s(target_rad, first_only=True)[0]

    def _polish(self, t: float, f) -> float:
        r = float(self.rate_radps(t))
        if r == 0.0:
            return t
        sign = 1.0 if self.mean_rate_radps >= 0 else -1.0
        t_new = t - f(t) / (sign * r)
        return t_new if abs(f(t_new)) <= abs(f(t)) else t
