"""index_harmonics: the indexing head's angle error (seed 003).

dtheta_idx(theta) = sum_{k=1..4} ck cos k theta + sk sin k theta is added to theta_e (physics.md, inputs).
"""

from __future__ import annotations

import numpy as np

from station.twin.effects.base import Effect, Param, Params, Terms
from station.twin.nonlinear_error import ARCSEC_RAD  # arc-second

ORDERS = (1, 2, 3, 4)


def static_angle_rad(p: Params, theta_rad: float) -> float:
    err = np.zeros(())
    for k in ORDERS:
        err = err + p[f"c{k}"] * np.cos(k * theta_rad) + p[f"s{k}"] * np.sin(k * theta_rad)
    return float(err)


EFFECT = Effect(
    name="index_harmonics",
    cause="indexing head angle error (seed 003)",
    # seed 003: arc-second angle errors of an indexing head; 20" at most.
    params={f"{c}{k}": Param("rad", typical=5e-6, bound=20 * ARCSEC_RAD) for k in ORDERS for c in ("c", "s")},
    injection={"c1": 5e-6, "s1": -3e-6, "c2": 2e-6, "s2": 4e-6, "c3": -1e-6, "s3": 1e-6, "c4": 1e-6, "s4": -5e-7},
    explanation="The indexing head does not reach the commanded angles: its error is a few harmonics of theta, "
    "arc-seconds each. Calibrate the head (the orthogonal 4-pose method of seed 003, or a polygon and "
    "autocollimator) and correct the positions.",
    separating="positions half-way between the recorded ones; the 4-pose method (seed 003) measures the "
    "harmonics directly",
    terms=Terms(static_angle_rad=static_angle_rad),
)
