"""The form of a rate noise a session does not state: constant per window, white over it, or a mixture.

physics.md allows a constant rate error per window (a repeatability) and white rate noise that averages down
as 1/sqrt(Tm), and a diagnosis must not assume either. The window-mean rate of point i has variance

    sigma0^2 (f + (1 - f) T_ref / Tm_i),

f the constant fraction at a reference window T_ref (a scale only). f is chosen from the data by the profile
likelihood of the joint fit (station.least_squares) refitted with each form's weights, sigma0 profiled out:

    l(f) = -(n / 2) ln(RSS_w(f) / n) + (1 / 2) sum ln w_i(f),   w_i(f) = 1 / (f + (1 - f) T_ref / Tm_i),

over RATE_FORM_GRID (ties go to the smaller f: with equal windows every f is the same fit).

The choice's own uncertainty (`choice_covariance`): the estimate of the chosen f differs from the estimate of the
f that holds by b_f - b_chosen; weighting every f by its likelihood, pi_f proportional to exp l(f) (white noise
given prior odds, the identification's rule for keeping it), the covariance of the chosen estimate is the fit's at
that f plus sum_f pi_f (b_f - b_chosen)(b_f - b_chosen)^T (zero with equal windows, where every f is one fit).

A pure function of rates, windows and design, in the core: both the identification (procedures) and the gap
diagnosis (station.gap, which may import only the core and the twin) call it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.least_squares import JointFit, fit_joint

RATE_FORM_GRID = (0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0)  # constant fraction f of the rate variance


def rate_variance_shape(tm_s: np.ndarray, ref_s: float, constant_fraction: float) -> np.ndarray:
    """var(wbar_i) / sigma0^2 = f + (1 - f) T_ref / Tm_i."""
    f = constant_fraction
    return f + (1.0 - f) * ref_s / np.asarray(tm_s, dtype=float)


@dataclass(frozen=True)
class FormFit:
    """The joint fit with one form's weights and its profile likelihood l(f)."""

    fit: JointFit
    likelihood: float


def form_fits(
    rates_radps: np.ndarray,
    level_index: np.ndarray,
    regressors: np.ndarray,
    names: tuple[str, ...],
    tm_s: np.ndarray,
    ref_s: float,
) -> dict[float, FormFit]:
    """The fit and l(f) of every f of RATE_FORM_GRID (module docstring).

    Raises station.least_squares.FitError when the design cannot fit `names`."""
    n = len(rates_radps)
    out = {}
    for f in RATE_FORM_GRID:
        w = 1.0 / rate_variance_shape(tm_s, ref_s, f)
        fit = fit_joint(rates_radps, level_index, regressors, names, w)
        rss = float(np.sum(w * fit.residuals**2))
        out[f] = FormFit(fit, -0.5 * n * math.log(max(rss, 1e-300) / n) + 0.5 * float(np.sum(np.log(w))))
    return out


def choice_covariance(fits: dict[float, FormFit], chosen: float, white_prior_odds: float) -> np.ndarray:
    """sum_f pi_f (b_f - b_chosen)(b_f - b_chosen)^T, pi_f proportional to exp l(f) and white's (f = 0) times
    `white_prior_odds` (module docstring): what the choice of f adds to the chosen fit's covariance."""
    forms = list(fits)
    ll = np.array([fits[f].likelihood for f in forms])
    pi = np.exp(ll - ll.max()) * np.where(np.array(forms) == 0.0, white_prior_odds, 1.0)
    pi /= pi.sum()
    d = np.array([fits[f].fit.values - fits[chosen].fit.values for f in forms])
    return (d * pi[:, None]).T @ d


def most_likely(fits: dict[float, FormFit]) -> float:
    """The f of highest l(f), the smaller f on a tie."""
    best, best_ll = 0.0, -math.inf
    for f, ff in fits.items():
        if ff.likelihood > best_ll + 1e-9:
            best, best_ll = f, ff.likelihood
    return best
