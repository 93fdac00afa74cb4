"""The blind validation: injections scaled to the SNR asked for, and the scores computed from blind diagnoses."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

import station.twin.measurement
import station.twin.session_sim
from station.cli.cli import main
from station.gap import candidates as cl
from station.gap.design import PointDesign
from station.gap.forward import CALIBRATED, predict_full
from station.gap.validate import (
    _extra_signal,
    effect_snr,
    injected_effects,
    out_of_library,
    scaled_injection,
    step_sequence,
    within_bounds,
)
from station.twin.config import NoiseModel
from station.twin.plan import seed000_plan
from station.twin.session_sim import simulate_session


@pytest.fixture(scope="module")
def design(seed000_session):
    return PointDesign.from_session(seed000_session("null", None, 0.0, 1001)[0])


@pytest.mark.parametrize("effect", sorted(injected_effects()))
def test_an_injection_has_the_snr_asked_for(design, twin, effect):
    params = scaled_injection(design, twin, effect, 10.0)
    assert effect_snr(design, twin, effect, params) == pytest.approx(10.0, rel=0.02)


def test_an_injection_never_goes_beyond_the_plausible_bounds(design, twin):
    """seed000 needs a waveform error of about 0.8 mm for SNR 10 (a constant amplitude error is what kz..k3
    absorb); capped at the candidate's bounds (z0, z1 and |Zs1(w)| at every design frequency), the SNR reached
    falls by the same factor (the signature is nearly linear in z0, z1: a 5 % tolerance)."""
    asked = scaled_injection(design, twin, "waveform_fundamental", 10.0)
    capped = within_bounds(design, "waveform_fundamental", asked)
    w = 2 * np.pi * np.unique(design.freq_hz[design.vib])
    share = {
        fp.param: abs(capped[fp.param]) / fp.bound
        for fp in cl.LIBRARY["waveform_fundamental"].free
        if fp.param in capped
    }
    zs1_bound_m = cl.LIBRARY["waveform_fundamental"].effect.joint_bound.bound
    share["Zs1"] = float(np.max(np.abs(capped["z0"] + capped["z1"] * w))) / zs1_bound_m
    assert max(share.values()) == pytest.approx(1.0, rel=1e-9), share  # the tightest bound is reached, none passed
    factor = capped["z0"] / asked["z0"]
    assert factor < 0.5
    assert effect_snr(design, twin, "waveform_fundamental", capped) == pytest.approx(10.0 * factor, rel=0.05)
    small = scaled_injection(design, twin, "cross_coupling", 10.0)  # kip of ~1e-6, far inside 1e-4
    assert within_bounds(design, "cross_coupling", small) == small


def test_an_out_of_library_term_reaches_the_simulated_rate_only_inside_its_context(twin):
    simulate, rate = station.twin.session_sim.simulate_point, station.twin.measurement.periodic_rate
    with out_of_library("bias_step", 1e-6, 40):
        assert station.twin.session_sim.simulate_point is not simulate
    with out_of_library("quartic_term", 1e-7, 40):
        assert station.twin.measurement.periodic_rate is not rate
    assert station.twin.session_sim.simulate_point is simulate and station.twin.measurement.periodic_rate is rate


@pytest.mark.parametrize(("kind", "value"), [("bias_step", 1e-6), ("quartic_term", 1e-6)])
def test_the_out_of_library_signal_is_what_the_simulator_adds(twin, kind, value):
    """Noise-free: the recorded rates minus the twin's exact window means at the recorded Tm, t1 are the term's."""
    quiet = replace(twin, noise=NoiseModel(timer_tick_s=0.0))
    plan = seed000_plan()
    with out_of_library(kind, value, len(plan)):
        session = simulate_session(plan, quiet, 1001)
    d = PointDesign.from_session(session)
    K = np.array([getattr(twin.instrument, c) for c in CALIBRATED])
    predicted, _ = predict_full(d, quiet, K)
    # Brent's Tm to ~1e-15 relative: 1e-15 of a 0.56 rad/s rate
    assert np.allclose(d.rate_radps - predicted, _extra_signal(kind, value, d, quiet), rtol=1e-9, atol=1e-13)
    if kind == "bias_step":
        assert np.count_nonzero(_extra_signal(kind, value, d, quiet)) == len(plan) - step_sequence(len(plan))


def test_a_small_blind_run_scores_what_it_diagnosed(tmp_path, capsys):
    out = tmp_path / "v.json"
    args = ["gap-validate", "--design", "seed000", "--snr", "10", "--reps", "1", "--nulls", "0"]
    args += ["--effects", "cross_coupling", "--out-of-library", "--workers", "1", "--quiet"]
    assert main([*args, "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    cases = doc["cases"]
    assert [c["kind"] for c in cases] == ["effect"]
    s = doc["summary"]["seed000"]
    effect = next(c for c in cases if c["kind"] == "effect")
    assert s["top1_at_snr10_identifiable"] == float(effect["effects"][:1] == ["cross_coupling"])
    assert s["null_false_attribution"] is None and s["n_null"] == 0
    assert s["out_of_library_explained_snr_ge10"] is None and s["out_of_library_by_effect"] == {}
    assert '"top1_at_snr10_identifiable"' in capsys.readouterr().out
