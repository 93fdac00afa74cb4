"""Exact window means of s = sin psi over a counter window (physics.md; seed 000 eq. 19).

With psi(t) = w (t - t1) and t2 = t1 + Np T - Tm, the means over [0, Tm] are
closed-form in t1 and t2; they hold for any root Tm.
"""

from __future__ import annotations

import numpy as np


def window_means(w_radps, Tm_s, t1_s, t2_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(<s>, <s^2>, <s^3>) over each window."""
    w, Tm, t1, t2 = (np.asarray(x, dtype=float) for x in (w_radps, Tm_s, t1_s, t2_s))
    wt = w * Tm
    c1 = np.cos(w * t1) - np.cos(w * t2)
    s1 = c1 / wt
    s2 = 0.5 - (np.sin(2 * w * t1) - np.sin(2 * w * t2)) / (4 * wt)
    s3 = (9.0 * c1 - (np.cos(3 * w * t1) - np.cos(3 * w * t2))) / (12 * wt)
    return s1, s2, s3


def nominal_means(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of a whole number of periods: <s> = 0, <s^2> = 1/2, <s^3> = 0 (seed 000 eq. 35)."""
    return np.zeros(n), np.full(n, 0.5), np.zeros(n)
