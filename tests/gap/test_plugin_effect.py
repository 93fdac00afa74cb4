"""An effect is a plug-in: a module's `Effect`, registered, reaches the twin, the candidates, the validation and the
report without a line changed elsewhere (station.twin.effects; README, "Adding an effect")."""

from __future__ import annotations

import html
import math

import numpy as np
import pytest

from station.gap import candidates as cl
from station.gap import validate
from station.gap.api import diagnose
from station.gap.report import render, summary_text
from station.twin.config import TwinConfig, TwinConfigError, default_twin
from station.twin.effects import EFFECTS, Effect, Param, Params, Terms, registered
from station.twin.inputs import instrument_rate_radps


def _rate(p: Params, a_i: np.ndarray, a_p: np.ndarray, a_o: np.ndarray) -> np.ndarray:
    return p["kp3"] * a_p**3


TOY = Effect(
    name="toy_ap_cubic",
    cause="a toy instrument term kp3 aP^3",
    params={"kp3": Param("rad/s/g^3", typical=1e-6, bound=1e-4)},
    injection={"kp3": 1e-6},
    explanation="A toy term for the plug-in test: the instrument's rate gains kp3 aP^3.",
    separating="positions near 90 and 270 deg",
    terms=Terms(rate_radps=_rate),
    check=lambda p: "" if abs(p["kp3"]) < 1.0 else "kp3 must be below 1 rad/s/g^3",
)


@pytest.fixture
def toy():
    with registered(TOY) as effect:
        yield effect
    assert TOY.name not in EFFECTS


def test_the_twin_takes_its_parameters_and_its_term(toy):
    twin = TwinConfig().with_effect(toy.name, kp3=2e-6)
    assert twin.effects[toy.name] == {"kp3": 2e-6}
    at_90_deg = (math.pi / 2, 0.0, 0.0)  # aP = 1
    shift = instrument_rate_radps(*at_90_deg, twin) - instrument_rate_radps(*at_90_deg, TwinConfig())
    assert shift == pytest.approx(2e-6, rel=1e-6)
    with pytest.raises(TwinConfigError, match="kp3 must be below 1"):
        TwinConfig().with_effect(toy.name, kp3=2.0)


def test_the_candidates_and_the_validation_take_it(toy):
    (fp,) = cl.LIBRARY[toy.name].free
    assert (fp.key, fp.unit, fp.scale, fp.bound) == ("toy_ap_cubic.kp3", "rad/s/g^3", 1e-6, 1e-4)
    assert toy.name in [c.name for c in cl.library()]
    assert toy.name in validate.injected_effects()
    assert {c.effect for c in validate.cases(["seed000"], [10.0], 1, 0, 1, ool=())} == set(EFFECTS)


def test_a_blind_validation_case_names_it_and_the_report_explains_it(toy):
    case = validate.Case("seed000", "effect", toy.name, 20.0, 7)
    session, injected = validate.make_session(case, default_twin())
    assert set(injected) == {"kp3"}
    report = diagnose(session, default_twin(), suggest=False)
    named = report.verdict.effects or report.verdict.ambiguous
    assert toy.name in named, (report.verdict.verdict, named)
    assert html.escape(toy.explanation) in render(report)
    assert toy.name in summary_text(report)
