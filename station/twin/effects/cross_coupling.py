"""cross_coupling: the instrument term kip aI aP (physics.md, rate model; seed 001's M_ip)."""

from __future__ import annotations

import numpy as np

from station.twin.effects.base import Effect, Param, Params, Terms


def rate_radps(p: Params, a_i: np.ndarray, a_p: np.ndarray, a_o: np.ndarray) -> np.ndarray:
    return p["kip"] * a_i * a_p


EFFECT = Effect(
    name="cross_coupling",
    cause="instrument term kip aI aP",
    params={"kip": Param("rad/s/g^2", typical=1e-6, bound=1e-4)},  # a PIGA's: 1e-6 to 1e-5, 1e-4 at most
    injection={"kip": 1e-6},
    explanation="The instrument has a cross-coupling term kip aI aP (seed 001's M_ip) that the model lacks. Add "
    "kip to the instrument model and calibrate it: positions away from 0 and 180 deg show it.",
    separating="positions half-way between the recorded ones (aI aP = sin 2 theta / 2)",
    terms=Terms(rate_radps=rate_radps),
)
