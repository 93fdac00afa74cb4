"""Identifiability in the session's design: absorbed and collinear candidates, and what would separate them."""

from __future__ import annotations

import pytest

from station.gap.api import diagnose
from station.gap.identifiability import ABSORBED_RHO, COLLINEAR_COS, CandidateId, IdentifiabilityReport
from station.twin.plan import multiposition_plan, seed000_plan
from station.twin.session_sim import simulate_session

KOQ = 1e-3  # rad/s/g^2: large, so that what kzz absorbs stands far above kzz's uncertainty


@pytest.fixture(scope="module")
def low_frequency_report(twin):
    """Positions within 60 deg of IA up and 1-2 Hz (a = A0 w^2 / g <= 0.48): aI = cos(theta) (1 - a sin psi)
    never changes sign, so koq aI|aI| is exactly koq aI^2, a change of kzz (physics.md rate model)."""
    plan = multiposition_plan([300.0, 330.0, 0.0, 30.0, 60.0], (1.0, 1.5, 2.0))
    session = simulate_session(plan, twin.with_effect("odd_quadratic", koq=KOQ), 4)
    return diagnose(session, twin, suggest=True)


def _param(report, candidate, key):
    cid = report.identifiability.candidates[candidate]
    return cid, next(p for p in cid.params if p.key == key)


def test_an_effect_the_calibrated_terms_absorb_is_reported_not_identifiable(low_frequency_report):
    cid, koq = _param(low_frequency_report, "odd_quadratic", "odd_quadratic.koq")
    assert koq.status == "absorbed" and koq.rho < ABSORBED_RHO
    assert not cid.identifiable and "absorbed" in cid.reason
    entry = next(c for c in low_frequency_report.candidates if c["name"] == "odd_quadratic")
    assert entry["rank"] is None and not entry["identifiable"]


def test_the_points_that_would_separate_it_are_named(low_frequency_report):
    _, koq = _param(low_frequency_report, "odd_quadratic", "odd_quadratic.koq")
    separates = {s.test: s.separates for s in koq.separating}
    # At 6 Hz a = 4.35 > 1: aI changes sign every period and aI|aI| is no longer aI^2.
    assert separates["add 6 Hz at every position"]
    # Half-way positions keep cos(theta) > 0 at a <= 0.48: still absorbed.
    half_way = next(t for t in separates if "half-way" in t)
    assert not separates[half_way]


def test_what_is_absorbed_leaves_no_gap_and_moves_kzz_by_koq(low_frequency_report, twin):
    assert low_frequency_report.verdict.verdict == "no_gap", low_frequency_report.verdict.text
    kzz = low_frequency_report.coefficients["twin_refit"]["kzz"]
    assert abs(kzz["value"] - (twin.instrument.kzz + KOQ)) < 4 * kzz["sigma"]
    assert abs(kzz["value"] - twin.instrument.kzz) > 4 * kzz["sigma"]


def test_a_collinear_pair_is_reported_and_told_apart_by_plausible_bounds(seed000_report, twin):
    """Ten equal positions: a constant tilt is in the span of the 8 index-angle harmonics (physics.md, seed 003).

    The design reports the collinearity; the fits decide. A 1" tilt (SNR 15) is reproduced by index errors
    of arc-seconds: cannot tell. A 62" tilt would need index harmonics beyond their 20" bound: only the
    tilt (and its exact alias, a constant table rotation ax0) is named, with the tilt fitted."""
    rep = seed000_report("null", None, 0.0, 1001, suggest=True)
    mount = rep.identifiability.candidates["mount_misalignment"]
    assert dict(mount.collinear_with)["index_harmonics"] > 0.99 > COLLINEAR_COS
    small = seed000_report("effect", "mount_misalignment", 15.0, 3)
    assert small.verdict.verdict == "cannot_tell", small.verdict.text
    assert {"mount_misalignment", "index_harmonics"} <= set(small.verdict.ambiguous)
    tilt_rad = 3e-4
    session = simulate_session(seed000_plan(), twin.with_effect("mount_misalignment", dtheta_mount=tilt_rad), 3)
    big = diagnose(session, twin, suggest=False)
    # a constant tilt is also exactly a constant parasitic rotation ax0 (physics.md): named, index errors not
    assert big.verdict.verdict == "cannot_tell", big.verdict.text
    assert set(big.verdict.ambiguous) == {"mount_misalignment", "parasitic_rotation"}, big.verdict.text
    entry = next(c for c in big.to_json()["candidates"] if c["name"] == "mount_misalignment")
    assert abs(entry["parameters"]["dtheta_mount"] - tilt_rad) < 4 * entry["uncertainty"]["dtheta_mount"]
    index = next(c for c in big.candidates if c["name"] == "index_harmonics")
    assert index["evidence"]["beyond_bounds"], index["evidence"]


def test_only_identifiable_candidates_are_ranked(seed000_report):
    rep = seed000_report("effect", "cross_coupling", 15.0, 3)
    ranked = [c for c in rep.candidates if c["rank"] is not None]
    assert [c["rank"] for c in ranked] == list(range(1, len(ranked) + 1))
    assert all(c["identifiable"] for c in ranked)
    assert all(c["rank"] is None for c in rep.candidates if not c["identifiable"])
    # the second ranking, by the held-out gap with each candidate alone, covers the same candidates
    assert sorted(c["evidence"]["heldout_rank"] for c in ranked) == [c["rank"] for c in ranked]
    best = min(ranked, key=lambda c: c["evidence"]["heldout_gap_with_it"])
    assert best["evidence"]["heldout_rank"] == 1 and best["name"] == "cross_coupling"
    json_ident = rep.to_json()["identifiability"]["candidates"]
    assert {c["name"] for c in json_ident} == {c["name"] for c in rep.candidates}


def test_a_group_joins_candidates_through_collinearity():
    report = IdentifiabilityReport(
        {
            "a": CandidateId("a", [], ["a.x"], [("b", 0.95)]),
            "b": CandidateId("b", [], ["b.x"], [("a", 0.95), ("c", 0.92)]),
            "c": CandidateId("c", [], ["c.x"], [("b", 0.92)]),
            "d": CandidateId("d", [], ["d.x"], []),
        }
    )
    assert set(report.group("a")) == {"a", "b", "c"}
    assert report.group("d") == ["d"]
    # collinearity is reported, not decided on: the fits judge whether one candidate reproduces another
    assert report.candidates["a"].identifiable and "nearly collinear with b" in report.candidates["a"].reason
