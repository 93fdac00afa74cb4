"""Where raw streams exist: the grating's harmonics and the pulse-rate spectrum against the twin's."""

from __future__ import annotations

from dataclasses import replace

import pytest

from station.gap.api import diagnose
from station.gap.design import PointDesign
from station.gap.rawstreams import raw_evidence
from station.gap.validate import scaled_injection, timing_stamp_sd_s
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session

PLAN = multiposition_plan([0.0, 45.0, 135.0, 180.0, 225.0, 315.0], (8.0, 10.0), window_s=20.0)


@pytest.fixture(scope="module")
def harmonics(twin):
    """Second and third harmonics of the table motion (seed 000 Table 5's kind), 15 times the noise."""
    design = PointDesign.from_session(simulate_session(PLAN, twin, 7))
    injected = scaled_injection(design, twin, "waveform_harmonics", 15.0)
    session = simulate_session(PLAN, twin.with_effect("waveform_harmonics", **injected), 7, raw=True)
    return session, injected, diagnose(session, twin, suggest=False)


def test_the_grating_measures_the_injected_harmonics(harmonics):
    """se: the fit's scatter and the phase error of the stamp t1 (50 ns tick, 0.1 us jitter)."""
    _, injected, rep = harmonics
    summary = rep.where["raw_streams"]["grating_summary"]
    for key in ("Zs2", "Zc2", "Zs3", "Zc3"):
        got = summary[f"{key}_m"]
        assert abs(got["value"] - injected[key]) < 4 * got["se"], key
        assert abs(got["value"]) > 100 * got["se"], key
    for key in ("z0_m", "z1_m_s_per_rad", "Zc1_m"):  # the fundamental is the twin's
        assert abs(summary[key]["value"]) < 4 * summary[key]["se"], key
    assert "grating differs from the twin in Zs2" in rep.where["summary"]


def test_the_period_and_the_pulse_rate_spectrum(harmonics, twin):
    session, _, rep = harmonics
    points = rep.where["raw_streams"]["points"]
    assert len(points) == sum(p.kind == "vibration" for p in session.points)
    for p in points:
        # the record's own frequency, 2 pi Np / (t2 + Tm - t1): stamps of 0.14 us over ~30 s
        assert p["measured_freq_hz"] == pytest.approx(p["twin_freq_hz"], rel=1e-7)
        second = p["pulse_rate_harmonics"][1]
        assert second["harmonic"] == 2
        if p["freq_hz"] == 10.0:  # the 2nd harmonic of a_z reaches the rate through kz aI
            assert second["difference_radps"] > 5 * second["se_radps"]


def test_raw_streams_without_pulse_directions_are_said_so(harmonics, twin):
    """piga-session/1 requires only pulse_t: without directions an up/down count cannot be rebuilt."""
    session, _, _ = harmonics
    pid = next(p.point_id for p in session.points if p.kind == "vibration")
    other_lab = replace(session, raw={pid: replace(session.raw[pid], pulse_dir=None)})
    evidence = raw_evidence(other_lab, PointDesign.from_session(other_lab), twin, timing_stamp_sd_s(twin))
    (entry,) = evidence["points"]
    assert "no pulse directions" in entry["pulse_rate_harmonics"] and "grating" in entry


def test_the_pulse_rate_spectrum_of_a_null_session_is_the_twins(twin):
    """Up/down edges give the precession angle at each level crossed; with the twin's own rate, every harmonic
    agrees within 4 se (the fit's scatter and the t1 stamp's phase error)."""
    plan = multiposition_plan([0.0, 45.0], (10.0,), window_s=30.0)
    session = simulate_session(plan, twin, 3, raw=True)
    evidence = raw_evidence(session, PointDesign.from_session(session), twin, timing_stamp_sd_s(twin))
    for point in evidence["points"]:
        for h in point["pulse_rate_harmonics"]:
            assert h["difference_radps"] < 4 * h["se_radps"], (point["point_id"], h)
        assert point["pulse_rate_harmonics"][0]["measured_radps"] > 4  # kz a cos(theta): a = 12.1 at 10 Hz


def test_pulse_edges_without_directions_are_counted_where_the_rate_never_reverses(twin):
    """piga-session/1 requires only pulse_t: at 2 Hz (a = 0.48) near IA up the rate keeps its sign, so
    every edge counts one way and the harmonics are those the recorded directions give."""
    plan = multiposition_plan([0.0, 30.0], (2.0,), window_s=30.0)
    session = simulate_session(plan, twin, 5, raw=True)
    design = PointDesign.from_session(session)
    sd = timing_stamp_sd_s(twin)
    with_dir = raw_evidence(session, design, twin, sd)["points"]
    bare = replace(session, raw={k: replace(v, pulse_dir=None) for k, v in session.raw.items()})
    without = raw_evidence(bare, design, twin, sd)["points"]
    assert len(without) == len(with_dir) == 2
    for a, b in zip(with_dir, without, strict=True):
        assert not isinstance(b["pulse_rate_harmonics"], str), b["pulse_rate_harmonics"]
        for ha, hb in zip(a["pulse_rate_harmonics"], b["pulse_rate_harmonics"], strict=True):
            assert hb["measured_radps"] == pytest.approx(ha["measured_radps"], rel=1e-12, abs=1e-15)
