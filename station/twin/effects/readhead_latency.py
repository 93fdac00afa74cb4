"""readhead_latency: the reference crossings are time-stamped late by delta (t1, t2 shifted)."""

from __future__ import annotations

from operator import itemgetter

from station.twin.effects.base import Effect, Param, Terms

EFFECT = Effect(
    name="readhead_latency",
    cause="reference crossings are time-stamped late",
    # a read head's electronics: microseconds, a millisecond at most.
    params={
        "delta": Param(
            "s",
            typical=1e-5,
            bound=1e-3,
            raw_measures="grating and reference marks see latency as a phase, like Zc1; "
            "a second reference (or frequencies far apart) separates them",
        )
    },
    injection={"delta": 1e-5},
    explanation="The read head's reference crossings are stamped delta late, which shifts the vibration phase "
    "the window means are computed at. Measure the read head's and counter's delay (a pulse of known time) and "
    "subtract it from t1 and t2.",
    separating="a second low frequency with short windows, or a second reference mark, separates latency from the "
    "fundamental's phase Zc1",
    terms=Terms(reference_latency_s=itemgetter("delta")),
)
