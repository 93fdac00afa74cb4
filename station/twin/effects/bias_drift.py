"""bias_drift: the bias wanders over the session (seed 001, thermal): k0 + d t_session."""

from __future__ import annotations

from operator import itemgetter

from station.twin.effects.base import Effect, Param, Terms

EFFECT = Effect(
    name="bias_drift",
    cause="bias wanders over the session",
    # about 1e-6 rad/s of bias wander over a 7 h session; at most a drift as large as k0 (1e-4 rad/s in 3 h).
    params={"d": Param("rad/s^2", typical=4e-11, bound=1e-8, fd_fraction=1.0)},
    injection={"d": 4e-11},
    explanation="The instrument's bias drifts over the session (thermal settling, seed 001). Let it warm up "
    "longer, control its temperature, or repeat a reference position through the run to track the drift.",
    separating="repeats of one position through the run, or the frequencies in alternating order",
    terms=Terms(bias_slope_radps2=itemgetter("d")),
)
