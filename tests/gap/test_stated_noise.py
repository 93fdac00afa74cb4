"""Stated noise (session.json, physics.md) is used as known; bad values are refused; otherwise noise is estimated.

The twin's seed-000 sessions have windows of about 560 s and white rate noise of 1e-6 rad/s
at 560 s (its NoiseModel), so each window's mean rate has sd 1e-6 rad/s within a few per cent:
stating that repeatability is stating the truth; stating a third of it is stating a lie the
chi-square test of the rate rows must catch (40 points, ~35 dof: rss/sigma^2 ~ 9 x 35).
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from station.gap.api import diagnose
from station.gap.design import GapInputError
from station.gap.noise import StatedNoise

TRUE_REPEATABILITY_RADPS = 1e-6  # the default twin's rate_noise_radps at rate_noise_ref_s = 560 s


def _stated(session, **meta):
    return replace(session, meta={**session.meta, **meta})


@pytest.mark.parametrize(
    ("meta", "message"),
    [
        ({"instrument_repeatability_radps": -1e-6}, "instrument_repeatability_radps = -1e-06"),
        ({"instrument_repeatability_radps": 0}, "instrument_repeatability_radps = 0"),
        ({"timing": {"timing_sigma_s": "fast"}}, "timing.timing_sigma_s = 'fast'"),
        ({"grating": {"noise_m": math.inf}}, "grating.noise_m = inf"),
        ({"timing": 3}, "timing = 3: must be an object"),
    ],
)
def test_a_bad_stated_noise_is_refused_naming_key_and_value(meta, message):
    with pytest.raises(GapInputError, match="session.json " + message.replace("(", r"\(").replace(")", r"\)")):
        StatedNoise.from_meta(meta)


def test_stated_timing_gives_the_stamp_sd_from_jitter_and_resolution():
    st = StatedNoise.from_meta({"timing": {"timing_sigma_s": 1e-7, "timer_resolution_s": 5e-8}})
    assert st.stamp_sd_s(1e-9) == pytest.approx(math.sqrt(1e-14 + 25e-16 / 12.0), rel=1e-12)
    assert StatedNoise.from_meta({}).stamp_sd_s(5e-8) is None


def test_a_stated_jitter_without_its_resolution_still_counts_the_ticks_quantum():
    """Stamps counted in 50 ns ticks carry a uniform rounding error of variance q^2 / 12 whether or not the
    session states q: with a jitter of 2e-8 s it is a third of the stamp's variance (4e-16 + 2.08e-16 s^2)."""
    st = StatedNoise.from_meta({"timing": {"timing_sigma_s": 2e-8}})
    assert st.stamp_sd_s(5e-8) == pytest.approx(math.sqrt(4e-16 + 25e-16 / 12.0), rel=1e-12)


def test_the_true_stated_noise_is_used_and_a_null_session_has_no_gap(seed000_session, twin):
    session, _ = seed000_session("null", None, 0.0, 1001)
    timing = {"timing_sigma_s": twin.noise.timing_jitter_s, "timer_resolution_s": twin.noise.timer_tick_s}
    rep = diagnose(_stated(session, instrument_repeatability_radps=TRUE_REPEATABILITY_RADPS, timing=timing), twin)
    assert rep.verdict.verdict == "no_gap", rep.verdict.text
    assert rep.noise["rate_noise_known"] and rep.noise["timing_noise_known"]
    assert rep.noise["sigma0_radps"] == TRUE_REPEATABILITY_RADPS and "stated" in rep.noise["source"]
    names = {t["name"] for t in rep.where["structure_tests_before"]}
    assert {"rate_goodness_of_fit", "timing_goodness_of_fit"} <= names


def test_a_stated_noise_three_times_too_small_is_caught_not_reestimated(seed000_session, twin):
    session, _ = seed000_session("null", None, 0.0, 1001)
    rep = diagnose(_stated(session, instrument_repeatability_radps=TRUE_REPEATABILITY_RADPS / 3), twin)
    assert rep.verdict.verdict != "no_gap", rep.verdict.text
    gof = next(t for t in rep.where["structure_tests_before"] if t["name"] == "rate_goodness_of_fit")
    assert gof["p_value"] < 1e-10 and "rate_goodness_of_fit" in rep.verdict.text


def test_without_stated_noise_it_is_estimated_with_its_dof(seed000_report):
    rep = seed000_report("null", None, 0.0, 1001)
    assert not rep.noise["rate_noise_known"] and rep.noise["sigma0_dof"] > 20
    # estimated within the chi-square spread of ~30 dof around the twin's 1e-6 rad/s: +-40 % at 3 sigma
    assert abs(rep.noise["sigma0_radps"] / TRUE_REPEATABILITY_RADPS - 1.0) < 0.4
    assert "rate_goodness_of_fit" not in {t["name"] for t in rep.where["structure_tests_before"]}
