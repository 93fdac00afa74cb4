"""Each verdict reached on simulated seed-000 sessions, with tolerances in units of the noise.

Effects are injected at SNR 15 after the calibrated terms are projected out
(station.gap.validate.scaled_injection), so for a one-parameter effect the
fitted value over its uncertainty must be about 15 too (|p| / sigma_p is the
same projected norm); sigma0 is estimated from about 25 residual dof, so
that ratio is allowed 0.7x to 1.4x.
"""

from __future__ import annotations

import pytest

SNR = 15.0
SEED = 3


@pytest.mark.parametrize(
    ("effect", "parameter"),
    [
        ("cross_coupling", "kip"),
        ("frequency_error", "eps_f"),
        ("parasitic_rotation", "axs1"),
    ],
)
def test_an_injected_library_effect_is_explained_by_name(seed000_session, seed000_report, effect, parameter):
    _, injected = seed000_session("effect", effect, SNR, SEED)
    rep = seed000_report("effect", effect, SNR, SEED)
    assert rep.verdict.verdict == "explained", rep.verdict.text
    assert rep.effects == [effect]
    entry = next(c for c in rep.to_json()["candidates"] if c["name"] == effect)
    assert entry["rank"] == 1 and entry["identifiable"] and entry["accepted"]
    # The held-out gap after is noise: within 3 se of 0, so it removes >= 80 % of a gap of this size.
    assert entry["heldout_shrink"] >= 0.8
    assert abs(rep.gap_after.G) < 3 * rep.gap_after.se
    assert 10 * rep.gap_before.se < rep.gap_before.G
    for key, value in entry["parameters"].items():
        assert abs(value - injected[key]) < 4 * entry["uncertainty"][key], key
    if len(entry["parameters"]) == 1:
        ratio = abs(entry["parameters"][parameter]) / entry["uncertainty"][parameter]
        assert 0.7 * SNR < ratio < 1.4 * SNR


@pytest.mark.parametrize("seed", [1001])
def test_a_null_session_has_no_gap(seed000_report, twin, seed):
    rep = seed000_report("null", None, 0.0, seed, suggest=True)
    assert rep.verdict.verdict == "no_gap", rep.verdict.text
    assert rep.effects == [] and not rep.verdict.ambiguous
    assert abs(rep.gap_before.G) < 3 * rep.gap_before.se  # chi-square_1 rows: se = sqrt(2 / rows)
    assert rep.twin_out == twin  # unchanged
    assert all(c["rank"] is None or not c["accepted"] for c in rep.candidates)


def test_an_out_of_library_term_is_not_declared_explained(seed000_report):
    """k4 aI^4 is no library effect (its nearest look-alike keeps cos < 0.75 in this design)."""
    rep = seed000_report("out_of_library", "quartic_term", 20.0, SEED)
    assert rep.verdict.verdict in ("unexplained", "cannot_tell"), rep.verdict.text
    assert rep.effects == []


def test_a_bias_step_is_never_explained_and_the_run_order_shows_it(seed000_report):
    """A k0 step mid-session (no library effect): one bias k0 for the session cannot absorb it, so the twin
    refitted leaves a gap that a structure test of position or run order finds; positions are visited in order,
    so position effects (a tilt, odd_quadratic) can mimic part of it, never all of it within every test."""
    rep = seed000_report("out_of_library", "bias_step", 20.0, SEED)
    assert rep.verdict.verdict in ("unexplained", "cannot_tell"), rep.verdict.text
    assert rep.effects == []
    significant = [t for t in rep.where["structure_tests_before"] if t["p_value"] is not None and t["p_value"] < 1e-3]
    assert {t["name"] for t in significant} & {"position_offsets", "time_trend", "run_order_blocks"}, significant


def test_an_effect_this_design_cannot_separate_gives_cannot_tell_with_the_points_that_would(seed000_report):
    """A constant mount tilt lies in the span of the 8 index-angle harmonics at 10 equal positions."""
    rep = seed000_report("effect", "mount_misalignment", SNR, SEED, suggest=True)
    assert rep.verdict.verdict == "cannot_tell", rep.verdict.text
    assert {"mount_misalignment", "index_harmonics"} <= set(rep.verdict.ambiguous)
    assert rep.effects == []


def test_an_effect_whose_model_fails_out_of_sample_is_not_explained():
    """In-sample tests all pass, but the held-out gap left is 30 se: the effect does not generalise."""
    from station.gap.attribute import Scored, Selection
    from station.gap.identifiability import IdentifiabilityReport
    from station.gap.verdict import HELDOUT_AFTER_SE, NoiseCheck, decide

    chosen = Scored("index_harmonics", None, 50.0, 1e-20, 0.0, -80.0, 400.0, 0.0)
    selection = Selection([chosen], [[chosen]], None)
    none = NoiseCheck("none", None, None)
    args = (10, selection, IdentifiabilityReport({}), [], [], none, none, 0.9)
    assert decide(*args, (0.1, 0.1)).verdict == "explained"
    v = decide(*args, (3.0 * HELDOUT_AFTER_SE * 0.1 / 2, 0.1))
    assert v.verdict == "unexplained" and v.partial == ["index_harmonics"]
    assert "held-out gap with the effects" in v.text
