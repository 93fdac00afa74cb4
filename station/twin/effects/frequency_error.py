"""frequency_error: the true frequency differs from the commanded one: w = w_cmd (1 + eps_f)."""

from __future__ import annotations

from operator import itemgetter

from station.twin.effects.base import Effect, Param, Terms

EFFECT = Effect(
    name="frequency_error",
    cause="true frequency differs from the commanded one",
    # seed 000 Table 6: sigma_f / f up to 2e-5; a drive's frequency error 5e-4 at most.
    params={
        "eps_f": Param(
            "1",
            typical=1e-5,
            bound=5e-4,
            fd_fraction=1e-4,
            timing=True,
            raw_measures="the grating and reference marks give the true frequency directly",
        )
    },
    injection={"eps_f": 1e-5},
    explanation="The table turns at w_cmd (1 + eps_f), not at the commanded frequency: the period identity "
    "t1 + Np T - Tm = t2 breaks by about eps_f Np / f. Calibrate the drive's speed (or its encoder's clock) and "
    "use the measured period.",
    separating="the period identities of every vibration point measure it; longer windows measure it better",
    terms=Terms(frequency_offset=itemgetter("eps_f")),
)
