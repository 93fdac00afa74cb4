"""waveform_harmonics: higher harmonics of the table motion (seed 000 Table 5).

z(t) gains Zs2 sin 2psi + Zc2 cos 2psi + Zs3 sin 3psi + Zc3 cos 3psi (physics.md, table motion).
"""

from __future__ import annotations

from station.twin.effects.base import Effect, Param, Params, Terms

GRATING = "the grating measures the harmonics directly"


def table_harmonics(p: Params, w_radps: float) -> list[tuple[int, float, float]]:
    return [(j, p[f"Zs{j}"], p[f"Zc{j}"]) for j in (2, 3)]


EFFECT = Effect(
    name="waveform_harmonics",
    cause="higher harmonics of the table motion",
    # seed 000 Table 5: Zs2, Zc2 up to about 0.05 mm; third harmonic assumed half of that.
    params={
        "Zs2": Param("m", typical=2e-5, bound=1e-4, raw_measures=GRATING),
        "Zc2": Param("m", typical=2e-5, bound=1e-4, raw_measures=GRATING),
        "Zs3": Param("m", typical=1e-5, bound=1e-4, raw_measures=GRATING),
        "Zc3": Param("m", typical=1e-5, bound=1e-4, raw_measures=GRATING),
    },
    injection={"Zs2": 2.1e-6, "Zc2": -2.4e-6, "Zs3": 1.0e-6, "Zc3": -1.0e-6},  # seed 000 Table 5, 10 Hz
    explanation="The table's motion has second and third harmonics (a crank and connecting rod is not a pure "
    "sinusoid): they add j^2 w^2 Zsj to the acceleration. Measure them with the absolute grating and put them in "
    "the twin, or check the guide's play and the connecting rod.",
    separating="raw grating records measure the harmonics directly; a second crank amplitude separates them from "
    "the calibrated terms",
    terms=Terms(table_harmonics=table_harmonics),
)
