"""The form of a rate noise a session does not state: constant per window, white over it, or a mixture.

physics.md allows a constant rate error per window (a repeatability) and white rate noise that averages down
as 1/sqrt(Tm), and a diagnosis must not assume either. The window-mean rate of point i has variance

    sigma0^2 (f + (1 - f) T_ref / Tm_i),

f the constant fraction at a reference window T_ref (a scale only). f is chosen from the data by the profile
likelihood of the joint fit (station.least_squares) refitted with each form's weights, sigma0 profiled out:

    l(f) = -(n / 2) ln(RSS_w(f) / n) + (1 / 2) sum ln w_i(f),   w_i(f) = 1 / (f + (1 - f) T_ref / Tm_i),

over RATE_FORM_GRID (ties go to the smaller f: with equal windows every f is the same fit).

The choice's own uncertainty (`form_covariance`), in two parts:

- The variance: the fit's covariance at the chosen f holds only if that f holds. Every f within the one-sigma
  likelihood interval, l(f) >= l_max - 1/2 (LIKELIHOOD_INTERVAL), is one the data do not tell from the best; the
  chosen estimate b = M y has, if f holds, the covariance M diag(s_f^2 shape_f) M^T (s_f^2 that fit's own scale),
  which at the chosen f is the fit's. Each coefficient takes the largest of these variances, the excess over the
  fit's added on the diagonal. With unequal windows the forms weigh long and short windows differently: ky
  rests on the slow positions' long windows, and where white noise is kept on data whose noise is constant per
  window its true u is a median 1.35 times what white noise gives it (tests/indep, 10 positions, issue 32).
- The values: the estimate of the chosen f differs from the estimate of the f that holds by b_f - b_chosen;
  weighting every f by its likelihood, pi_f proportional to exp l(f) (white noise given prior odds, the
  identification's rule for keeping it), the choice adds sum_f pi_f (b_f - b_chosen)(b_f - b_chosen)^T
  (`choice_covariance`; zero with equal windows, where every f is one fit).

A pure function of rates, windows and design, in the core: both the identification (procedures) and the gap
diagnosis (station.gap, which may import only the core and the twin) call it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.least_squares import JointFit, fit_joint

RATE_FORM_GRID = (0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0)  # constant fraction f of the rate variance
# the forms the data do not tell from the best: l(f) >= l_max - 1/2, the one-sigma likelihood interval
LIKELIHOOD_INTERVAL = 0.5


def rate_variance_shape(tm_s: np.ndarray, ref_s: float, constant_fraction: float) -> np.ndarray:
    """var(wbar_i) / sigma0^2 = f + (1 - f) T_ref / Tm_i."""
    f = constant_fraction
    return f + (1.0 - f) * ref_s / np.asarray(tm_s, dtype=float)


@dataclass(frozen=True)
class FormFit:
    """The joint fit with one form's weights, its profile likelihood l(f) and the form's shape f + (1 - f) T_ref / Tm
    (the rate variances up to the scale, fit.sigma_residual^2)."""

    fit: JointFit
    likelihood: float
    shape: np.ndarray


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
        shape = rate_variance_shape(tm_s, ref_s, f)
        w = 1.0 / shape
        fit = fit_joint(rates_radps, level_index, regressors, names, w)
        rss = float(np.sum(w * fit.residuals**2))
        out[f] = FormFit(fit, -0.5 * n * math.log(max(rss, 1e-300) / n) + 0.5 * float(np.sum(np.log(w))), shape)
    return out


def form_covariance(fits: dict[float, FormFit], chosen: float, white_prior_odds: float) -> np.ndarray:
    """The covariance of the chosen f's estimates, the choice's uncertainty in it (module docstring): each
    coefficient's variance the largest of M diag(s_f^2 shape_f) M^T over the f with l(f) >= l_max - 1/2 (the excess
    over the chosen fit's added on the diagonal, so no combination of the coefficients has a smaller variance than
    the chosen fit gives it), plus choice_covariance."""
    fit = fits[chosen].fit
    ll_max = max(ff.likelihood for ff in fits.values())
    var = np.diag(fit.cov).copy()
    for ff in fits.values():
        if ff.likelihood >= ll_max - LIKELIHOOD_INTERVAL:
            rate_var = ff.fit.sigma_residual**2 * ff.shape
            var = np.maximum(var, np.einsum("ij,j,ij->i", fit.estimator, rate_var, fit.estimator))
    return fit.cov + np.diag(var - np.diag(fit.cov)) + choice_covariance(fits, chosen, white_prior_odds)


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
