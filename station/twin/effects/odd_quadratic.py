"""odd_quadratic: the instrument term koq aI|aI| (physics.md, rate model; not polynomial once a > 1)."""

from __future__ import annotations

import numpy as np

from station.twin.effects.base import Effect, Param, Params, Terms


def rate_radps(p: Params, a_i: np.ndarray, a_p: np.ndarray, a_o: np.ndarray) -> np.ndarray:
    return p["koq"] * a_i * np.abs(a_i)


EFFECT = Effect(
    name="odd_quadratic",
    cause="instrument term koq aI|aI|",
    params={"koq": Param("rad/s/g^2", typical=1e-6, bound=1e-4)},  # a PIGA's: 1e-6 to 1e-5, 1e-4 at most
    injection={"koq": 1e-6},
    explanation="The instrument has an odd quadratic term koq aI|aI| that the polynomial model lacks. Add koq to "
    "the instrument model and calibrate it (vibration at a > 1 shows it; statics alone do not).",
    separating="vibration at amplitude ratios below and above 1 (another frequency or crank amplitude)",
    terms=Terms(rate_radps=rate_radps),
)
