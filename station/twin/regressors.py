"""Regressors of Y = wbar(vibration) - wbar(static) for the nominal rate model (physics.md).

aI = cos theta (1 - a s), aP = sin theta (1 - a s); the window means turn the
rate model into a linear model in (kz, kzz, ky, k3). A measured parasitic
rotation axs1 (seed 000 eq. 17, Table 7) adds, to first order in axs1, the
kz term -kz axs1 sin theta <s (1 - a s)>.
"""

from __future__ import annotations

import numpy as np

COEFFICIENTS = ("kz", "kzz", "ky", "k3")
BASELINE_COEFFICIENTS = ("kzz", "ky", "k3")


def integral_regressors(theta_rad, a, s1, s2, s3, axs1_rad: float = 0.0) -> np.ndarray:
    """Columns (kz, kzz, ky, k3) of seed 000 eq. 19 with exact window means."""
    theta, a, s1, s2, s3 = (np.asarray(x, dtype=float) for x in (theta_rad, a, s1, s2, s3))
    c, s = np.cos(theta), np.sin(theta)
    quad = -2 * a * s1 + a * a * s2
    kz = -a * s1 * c + axs1_rad * s * (a * s2 - s1)
    return np.column_stack([kz, quad * c * c, quad * s * s, (-3 * a * s1 + 3 * a * a * s2 - a**3 * s3) * c**3])


def baseline_regressors(theta_rad, a) -> np.ndarray:
    """Columns (kzz, ky, k3) of the integer periodic vibration model (seed 000 eq. 35)."""
    theta, a = np.asarray(theta_rad, dtype=float), np.asarray(a, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    half = 0.5 * a * a
    return np.column_stack([half * c * c, half * s * s, 3 * half * c**3])
