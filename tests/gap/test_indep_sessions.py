"""Sessions the twin did not make: piga-session/1 directories written by tests/indep (no project code),
diagnosed blind against the default twin, read back through station.interchange as a lab's would be.

Each case's truth comes from indep (its effect scaled to an SNR on the channel it shows in, its noise
stated in session.json or not); the diagnosis is told nothing but the directory.
"""

from __future__ import annotations

import functools
from pathlib import Path

import pytest

from station.gap.api import diagnose, summary_text
from station.gap.report import GapReport
from station.interchange import read_session
from station.twin.config import default_twin

indep = pytest.importorskip("indep.cases")


@functools.cache
def _case(seed: int, kind: str, snr: float | None, family: str) -> tuple[dict, GapReport]:
    import tempfile

    out = Path(tempfile.mkdtemp(prefix="gap_indep_")) / "s"
    truth = indep.make_case(seed, kind, out, snr=snr, family=family)
    return truth, diagnose(read_session(out), default_twin(), suggest=False)


def test_a_null_session_of_another_design_has_no_gap():
    truth, rep = _case(100000, "null", None, "equal_angle")
    assert truth["effects"] == [] and truth["n_points"] == rep.session_info["n_points"]
    assert rep.verdict.verdict == "no_gap", rep.verdict.text
    assert rep.effects == [] and not rep.verdict.ambiguous
    assert abs(rep.gap_before.G) < 3 * rep.gap_before.se


def test_a_strong_library_effect_is_explained_with_its_parameter():
    """cross_coupling at SNR 30: kip found within 4 of its standard uncertainties of the truth."""
    truth, rep = _case(100020, "cross_coupling", 30.0, "equal_angle")
    assert rep.verdict.verdict == "explained" and rep.effects == ["cross_coupling"], rep.verdict.text
    entry = next(c for c in rep.to_json()["candidates"] if c["name"] == "cross_coupling")
    kip, sd = entry["parameters"]["kip"], entry["uncertainty"]["kip"]
    assert abs(kip - truth["params"]["cross_coupling"]["kip"]) < 4 * sd
    assert 15 < abs(kip) / sd < 60  # SNR 30 on the rate channel; the calibrated terms take part of it
    assert entry["heldout_shrink"] >= 0.8
    assert f"kip = {kip:.4g} ± {sd:.2g}" in summary_text(rep)


@pytest.mark.parametrize(("seed", "kind"), [(100042, "ool:scale_asymmetry"), (100045, "ool:thermal_transient")])
def test_an_out_of_library_effect_is_never_explained_and_the_rejecting_test_is_named(seed, kind):
    truth, rep = _case(seed, kind, 10.0, "equal_angle")
    assert not truth["in_library"]
    assert rep.verdict.verdict in ("unexplained", "cannot_tell"), rep.verdict.text
    assert rep.effects == []
    tests = rep.where["structure_tests_after" if rep.verdict.partial else "structure_tests_before"]
    rejecting = [t["name"] for t in tests if t["p_value"] is not None and t["p_value"] < 1e-4]
    assert rejecting and all(name in rep.verdict.text for name in rejecting[:1]), rep.verdict.text
    assert "tests that reject the model" in summary_text(rep)
