"""The form of a rate noise a session does not state: constant per window, white over it, or a mixture.

physics.md allows a constant rate error per window (a repeatability) and white rate noise that averages down
as 1/sqrt(Tm), and a diagnosis must not assume either. The window-mean rate of point i has variance

    sigma0^2 (f + (1 - f) T_ref / Tm_i),

f the constant fraction at a reference window T_ref (a scale only). f is chosen from the data by the profile
likelihood of the joint fit (station.least_squares) refitted with each form's weights, sigma0 profiled out:

    l(f) = -(n / 2) ln(RSS_w(f) / n) + (1 / 2) sum ln w_i(f),   w_i(f) = 1 / (f + (1 - f) T_ref / Tm_i),

over RATE_FORM_GRID (ties go to the smaller f: with equal windows every f is the same fit).

A pure function of rates, windows and design, in the core: both the identification (procedures) and the gap
diagnosis (station.gap, which may import only the core and the twin) call it.
"""

from __future__ import annotations

import math

import numpy as np

from station.least_squares import fit_joint

RATE_FORM_GRID = (0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0)  # constant fraction f of the rate variance


def rate_variance_shape(tm_s: np.ndarray, ref_s: float, constant_fraction: float) -> np.ndarray:
    """var(wbar_i) / sigma0^2 = f + (1 - f) T_ref / Tm_i."""
    f = constant_fraction
    return f + (1.0 - f) * ref_s / np.asarray(tm_s, dtype=float)


def form_likelihoods(
    rates_radps: np.ndarray,
    level_index: np.ndarray,
    regressors: np.ndarray,
    names: tuple[str, ...],
    tm_s: np.ndarray,
    ref_s: float,
) -> dict[float, float]:
    """l(f) of every f of RATE_FORM_GRID (module docstring).

    Raises station.least_squares.FitError when the design cannot fit `names`."""
    n = len(rates_radps)
    out = {}
    for f in RATE_FORM_GRID:
        w = 1.0 / rate_variance_shape(tm_s, ref_s, f)
        fit = fit_joint(rates_radps, level_index, regressors, names, w)
        rss = float(np.sum(w * fit.residuals**2))
        out[f] = -0.5 * n * math.log(max(rss, 1e-300) / n) + 0.5 * float(np.sum(np.log(w)))
    return out


def most_likely(likelihoods: dict[float, float]) -> float:
    """The f of highest l(f), the smaller f on a tie."""
    best, best_ll = 0.0, -math.inf
    for f, ll in likelihoods.items():
        if ll > best_ll + 1e-9:
            best, best_ll = f, ll
    return best
