"""Honest noise: stated by the session, else estimated from repeats or the residual dof.

Stated noise (session.json, physics.md): `instrument_repeatability_radps` is one
sigma of every window's mean rate whatever its length; `timing.timing_sigma_s`
and `timing.timer_resolution_s` give each stamp's sd sqrt(sigma^2 + res^2 / 12) (the twin's tick
where the resolution is not stated);
`grating.noise_m` each grating sample's. Stated values are used as known
(chi-square tests of each channel); nothing else is ever taken as a noise level.

Unstated rate noise may be per-window constant (a repeatability) or white rate
noise that averages down as 1/sqrt(Tm): the window-mean rate of point i has
variance sigma0^2 (f + (1 - f) T_ref / Tm_i), the fraction f chosen by the
profile likelihood of the twin refitted (station.noise_form, shared with identification), T_ref a reference
window only; the two time stamps that bound Tm add (wbar_i sigma_tau / Tm_i)^2,
since wbar = 2 pi P / (16384 Tm). sigma0 is then estimated from the data and
its own uncertainty carried into the tests (F, never chi-square with it as known):
- from repeats (points with the same position, frequency and kind): the
  spread of their residuals about the group mean (pure error, independent of
  any model gap that repeats share), when it has PURE_ERROR_MIN_DOF dof;
- otherwise from the residuals of the final model, sigma0^2 = sum w_i e_i^2 / dof
  (seed 000 eq. 21 with these weights), after the generic structure that the
  structure tests found significant (station.gap.localise) is taken out too,
  so that a gap the library does not explain is not mistaken for noise.
The period identity tau = t2 - t1 + Tm - Np T has the noise of two time
stamps: sigma_tau is estimated from its scatter once a single frequency error
is allowed for, never below the counter's quantisation, tick sqrt(2 / 12).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from station.gap.design import GapInputError, PointDesign
from station.noise_form import rate_variance_shape
from station.twin.config import TwinConfig

PURE_ERROR_MIN_DOF = 5


@dataclass(frozen=True)
class StatedNoise:
    """Noise stated by session.json (physics.md); None where the session does not state it."""

    repeatability_radps: float | None = None
    timing_sigma_s: float | None = None
    timer_resolution_s: float | None = None
    grating_noise_m: float | None = None

    @classmethod
    def from_meta(cls, meta: dict) -> StatedNoise:
        """Read and check the optional keys; a bad value is refused naming the key, the value and what is allowed."""

        def get(where: dict, key: str, label: str) -> float | None:
            if key not in where or where[key] is None:
                return None
            v = where[key]
            ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
            if not ok:
                raise GapInputError(f"session.json {label} = {v!r}: a noise level must be a finite number >= 0")
            return float(v)

        def sub(key: str) -> dict:
            v = meta.get(key) or {}
            if not isinstance(v, dict):
                raise GapInputError(f"session.json {key} = {v!r}: must be an object")
            return v

        timing, grating = sub("timing"), sub("grating")
        rep = get(meta, "instrument_repeatability_radps", "instrument_repeatability_radps")
        if rep == 0.0:
            raise GapInputError("session.json instrument_repeatability_radps = 0: must be > 0 (one sigma of a rate)")
        return cls(
            rep,
            get(timing, "timing_sigma_s", "timing.timing_sigma_s"),
            get(timing, "timer_resolution_s", "timing.timer_resolution_s"),
            get(grating, "noise_m", "grating.noise_m"),
        )

    def stamp_sd_s(self, default_tick_s: float) -> float | None:
        """sd of one stamp, jitter and quantisation: sqrt(sigma^2 + q^2 / 12) (a uniform rounding error of
        quantum q), q the stated resolution, else default_tick_s: a session that states its jitter but not its
        resolution is still counted in the counter's ticks (physics.md: 50 ns). None unless the jitter is stated."""
        if self.timing_sigma_s is None:
            return None
        q = self.timer_resolution_s if self.timer_resolution_s is not None else default_tick_s
        return math.sqrt(self.timing_sigma_s**2 + q * q / 12.0)

    def to_json(self) -> dict:
        return {
            "instrument_repeatability_radps": self.repeatability_radps,
            "timing_sigma_s": self.timing_sigma_s,
            "timer_resolution_s": self.timer_resolution_s,
            "grating_noise_m": self.grating_noise_m,
        }


def timing_rate_sd_radps(design: PointDesign, sigma_tau_s: float) -> np.ndarray:
    """Rate error from the two stamps that bound Tm: |wbar| sigma_tau / Tm."""
    return np.abs(design.rate_radps) * sigma_tau_s / design.Tm_s


def rate_weights(
    design: PointDesign,
    twin: TwinConfig,
    sigma_tau_s: float = 0.0,
    sigma0_radps: float = math.inf,
    constant_fraction: float = 0.0,
) -> np.ndarray:
    """w_i = sigma0^2 / var(wbar_i) = 1 / (f + (1 - f) T_ref / Tm_i + (timing sd_i / sigma0)^2)."""
    var = rate_variance_shape(design.Tm_s, twin.noise.rate_noise_ref_s, constant_fraction)
    if sigma_tau_s > 0 and math.isfinite(sigma0_radps):
        var = var + (timing_rate_sd_radps(design, sigma_tau_s) / sigma0_radps) ** 2
    return 1.0 / var


@dataclass(frozen=True)
class TimingNoise:
    sigma_tau_s: float
    dof: int
    floor_s: float
    eps_f_hat: float  # the single frequency error that the period identities imply
    stated: bool = False  # from session.json (known: chi-square tests), else estimated (dof above)


def timing_noise(design: PointDesign, twin: TwinConfig, stated: StatedNoise | None = None) -> TimingNoise:
    """sigma of the period identity (two stamps): stated, else its scatter once a single frequency error is fitted.

    The floor is the stamps' quantisation, tick sqrt(2 / 12) (the stated resolution, else the twin's tick)."""
    stated = stated or StatedNoise()
    tick = stated.timer_resolution_s if stated.timer_resolution_s is not None else twin.noise.timer_tick_s
    floor = tick * math.sqrt(2.0 / 12.0)
    v = design.vib
    span = design.Np[v] / design.freq_hz[v]  # Np T_cmd
    tau = design.tau_s[v]
    # tau = Np T_cmd (1 / (1 + eps) - 1) = span * x, linear in x.
    x = float(span @ tau / (span @ span)) if span.size else 0.0
    eps = 1.0 / (1.0 + x) - 1.0
    stamp_sd = stated.stamp_sd_s(tick)
    if stamp_sd is not None:
        return TimingNoise(max(math.sqrt(2.0) * stamp_sd, 1e-15), 0, floor, eps, True)
    dof = int(v.sum()) - 1
    if dof < 1:
        return TimingNoise(floor, 0, floor, eps)
    sd = math.sqrt(float(np.sum((tau - span * x) ** 2)) / dof)
    return TimingNoise(max(sd, floor), dof, floor, eps)


@dataclass(frozen=True)
class PureError:
    sigma0_radps: float
    dof: int
    groups: int


def pure_error(design: PointDesign, residuals_radps: np.ndarray, weights: np.ndarray) -> PureError | None:
    """sigma0 from repeats: weighted spread of residuals within (position, frequency, kind) groups."""
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(zip(np.round(design.position_deg, 6), np.round(design.freq_hz, 6), strict=True)):
        groups.setdefault(key, []).append(i)
    ss, dof, n_groups = 0.0, 0, 0
    for idx in groups.values():
        if len(idx) < 2:
            continue
        r, w = residuals_radps[idx], weights[idx]
        mean = float(np.sum(w * r) / np.sum(w))
        ss += float(np.sum(w * (r - mean) ** 2))
        dof += len(idx) - 1
        n_groups += 1
    return PureError(math.sqrt(ss / dof), dof, n_groups) if dof else None


@dataclass(frozen=True)
class HonestNoise:
    sigma0_radps: float
    dof: int
    source: str


def honest_noise(
    pe: PureError | None,
    r_white: np.ndarray,
    n_rate: int,
    dof: int,
    sigma_white_radps: float,
    structure: list[np.ndarray],
) -> HonestNoise:
    """sigma0 at T_ref: pure error, else the final model's rate residual (r_white: whitened by sigma_white,
    rate rows first) with the columns of the significant structure blocks (orthonormal, off the model) taken out."""
    if pe is not None and pe.dof >= PURE_ERROR_MIN_DOF:
        return HonestNoise(pe.sigma0_radps, pe.dof, "pure error of repeats")
    rss, source = float(r_white[:n_rate] @ r_white[:n_rate]), "residuals of the final model"
    if structure:
        U, s, _ = np.linalg.svd(np.hstack(structure), full_matrices=False)
        U = U[:, s > 1e-8 * s.max()]
        rss -= float(np.sum((U.T @ r_white) ** 2))
        dof -= U.shape[1]
        source += " after the significant structure (see where)"
    return HonestNoise(sigma_white_radps * math.sqrt(max(rss, 0.0) / dof), dof, source)


def excess_scatter_pvalue(sigma_hat: float, dof: int, sigma_ref: float) -> float:
    """P(chi2_dof >= dof sigma_hat^2 / sigma_ref^2): small when the scatter exceeds a stated (known) sigma."""
    if sigma_ref <= 0 or dof <= 0:
        return float("nan")
    return float(stats.chi2.sf(dof * (sigma_hat / sigma_ref) ** 2, dof))


def lack_of_fit_pvalue(rss_radps2: float, dof: int, pe: PureError) -> float:
    """F-test of the model's residual scatter against the pure error of repeats."""
    if dof <= pe.dof:
        return float("nan")
    lof = max(rss_radps2 - pe.sigma0_radps**2 * pe.dof, 0.0) / (dof - pe.dof)
    return float(stats.f.sf(lof / max(pe.sigma0_radps**2, 1e-300), dof - pe.dof, pe.dof))
