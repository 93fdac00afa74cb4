"""The forward model reproduces what the twin's simulator records, for every effect of physics.md's table."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from station.gap.design import PointDesign
from station.gap.forward import CALIBRATED, base_config, predict, predict_full
from station.gap.validate import injected_effects
from station.twin.config import NoiseModel
from station.twin.effects import EFFECTS
from station.twin.inputs import instrument_inputs, instrument_rate_radps, rate_from_inputs
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session

PLAN = multiposition_plan([0.0, 72.0, 144.0, 216.0, 288.0], (8.0, 10.0))


@pytest.mark.parametrize("effect", sorted(injected_effects()))
def test_window_means_and_period_identities_match_the_simulator(twin, effect):
    """Noise-free (tick 0): recorded wbar = phi(Tm) / Tm exactly, and tau = Np (T_true - T_cmd).

    Each effect at 100x its seed-000 size so that it moves the rates far above the 1e-12 tolerance."""
    declared = EFFECTS[effect]
    params = {k: 100 * v for k, v in declared.injection.items()} | dict(declared.nominal)
    cfg = replace(twin, noise=NoiseModel(timer_tick_s=0.0)).with_effect(effect, **params)
    d = PointDesign.from_session(simulate_session(PLAN, cfg, 2))
    K = np.array([getattr(cfg.instrument, c) for c in CALIBRATED])
    rate, tau = predict_full(d, cfg, K)
    np.testing.assert_allclose(rate, d.rate_radps, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(tau, d.tau_s, rtol=0.0, atol=1e-10)  # sums of ~560 s stamps: 1e-13 s rounding
    without, _ = predict_full(d, cfg.without_effect(effect), K)
    assert np.max(np.abs(rate - without)) > 1e-9  # the effect is visible at this size


def test_the_unit_columns_are_linear_in_the_calibrated_coefficients(twin):
    """rate = base + units K (levels referred to the static rate at each position)."""
    d = PointDesign.from_session(simulate_session(PLAN, twin, 2))
    pred = predict(d, twin)
    K = np.array([getattr(twin.instrument, c) for c in CALIBRATED])
    full, _ = predict_full(d, twin, K)
    referred = pred.base_radps + pred.units_radps @ K
    # the same up to one constant per position (the static levels)
    for j in range(d.positions_deg.size):
        at = d.pos_index == j
        diff = full[at] - referred[at]
        assert np.ptp(diff) < 1e-12


@pytest.mark.parametrize("effect", sorted(injected_effects()))
def test_the_base_rate_from_the_inputs_is_the_twins_rate_with_k0_and_K_zero(twin, effect):
    """predict's base (the rate model of base_config at the inputs of cfg, which it computes anyway) is
    instrument_rate_radps of base_config to the bit: the instrument's coefficients do not enter the inputs. At rest
    and over the crank phase, each effect at 100x its seed-000 size."""
    declared = EFFECTS[effect]
    cfg = twin.with_effect(effect, **({k: 100 * v for k, v in declared.injection.items()} | dict(declared.nominal)))
    psi = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    for theta, phases, w in ((0.3, np.zeros(1), 0.0), (2.1, psi, 2.0 * np.pi * 9.0)):
        expected = instrument_rate_radps(theta, phases, w, base_config(cfg))
        got = rate_from_inputs(instrument_inputs(theta, phases, w, cfg), base_config(cfg))
        np.testing.assert_array_equal(got, np.broadcast_to(expected, phases.shape))
