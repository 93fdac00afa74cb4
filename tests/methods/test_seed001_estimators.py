"""Seed 001 estimators without I/O: eq. 6 against the model it inverts, against the seed's own remarks on it,
and the stated uncertainties against the scatter of many simulated sessions.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from procedures.tumble.analysis import EQ6, analyse_tumble, position_deg
from procedures.tumble.report import render_tumble_report
from procedures.tumble.tumble_session import tumble_session
from station.twin.pendulous_accelerometer import CF_NAMES, AccelerometerModel, cf_coefficients, output_v

THETA = np.radians([position_deg(J) for J in range(1, 10)])


def test_eq6_inverts_the_conversion_function_exactly() -> None:
    """Eq. 1 sampled at the nine positions holds harmonics up to the third only: eq. 6 recovers it to rounding."""
    m = AccelerometerModel()
    for T in (-40.0, 20.0, 80.0):
        est = EQ6 @ output_v(m, THETA, T)
        truth = cf_coefficients(m, T)
        for name, value in zip(CF_NAMES, est, strict=True):
            assert value == pytest.approx(truth[name], abs=1e-14), (T, name)


def test_eq6_behaves_as_the_seed_says_under_a_setting_angle() -> None:
    """Seed 001 after eq. 6: with the instrument turned by d0, K1 reads K1 (1 - d0^2 / 2), Mip reads Mip - 2 K2 d0
    and Mo reads the angle (-K1 d0 in our sign); all to O(d0^2) relative, here 1e-6 (third order: 1e-9)."""
    d0 = 1e-3
    m = dataclasses.replace(AccelerometerModel(), delta_o_rad=0.0)
    k = cf_coefficients(m, m.reference_c)
    est = dict(zip(CF_NAMES, EQ6 @ output_v(m, THETA + d0, m.reference_c), strict=True))
    third_order = d0**3 * k["K1"]
    assert est["K1"] == pytest.approx(k["K1"] * (1 - d0**2 / 2), abs=10 * third_order + 3 * k["K3"] * d0**2)
    assert est["Mip"] == pytest.approx(k["Mip"] - 2 * k["K2"] * d0, abs=10 * third_order)
    assert est["Mo"] == pytest.approx(-k["K1"] * d0, abs=10 * third_order + k["K3"] * d0)


@pytest.mark.slow
def test_stated_uncertainties_match_the_scatter_of_simulated_sessions() -> None:
    """Normalised errors (estimate - truth) / sigma of N sessions (procedures.tumble.tumble_session: the procedure's
    readings from the model, returning to T0) are N(0, 1) if the sigmas are honest: their mean within 4 / sqrt(N)
    of 0 and their standard deviation within 4 / sqrt(2 N) of 1 (4 standard errors)."""
    m = AccelerometerModel()
    rng = np.random.default_rng(1)
    n = 200
    z: dict[str, list[float]] = {}
    for _ in range(n):
        session, truths = tumble_session(m, [20.0, 80.0, -40.0, 20.0], 3, sigma_g=8e-6, rng=rng)
        _, points, model = analyse_tumble(session, m.reference_c)
        for p, truth in zip(points, truths, strict=True):
            for name in CF_NAMES:
                value, sigma = p.coefficient(name)
                z.setdefault(f"{name}@T{p.block}", []).append((value - truth[name]) / sigma)
            z.setdefault(f"h@T{p.block}", []).append((p.hysteresis_g[0] - m.hysteresis_g) / p.hysteresis_g[1])
        laws = {"lambda_T1": (model.bias_g.above, m.lambda_above_g_per_c),
                "lambda_T2": (model.bias_g.below, m.lambda_below_g_per_c),
                "beta_T1": (model.scale_factor.above, m.beta_above_per_c),
                "beta_T2": (model.scale_factor.below, m.beta_below_per_c),
                "gamma_T1": (model.misalignment_rad.above, m.gamma_above_rad_per_c),
                "gamma_T2": (model.misalignment_rad.below, m.gamma_below_rad_per_c),
                "k0D": (model.bias_g.drift_per_s, m.drift_g_per_s)}  # fmt: skip
        for name, ((value, sigma), truth) in laws.items():
            z.setdefault(name, []).append((value - truth) / sigma)
    for name, errors in z.items():
        e = np.array(errors)
        assert abs(e.mean()) < 4 / math.sqrt(n), (name, e.mean())
        assert abs(e.std(ddof=1) - 1) < 4 / math.sqrt(2 * n), (name, e.std(ddof=1))


def test_a_session_on_one_side_of_t0_leaves_the_other_slope_unmeasured() -> None:
    m = AccelerometerModel()
    session, _ = tumble_session(m, [20.0, 60.0], 1, sigma_g=8e-6, rng=np.random.default_rng(3))
    r, points, model = analyse_tumble(session, m.reference_c)
    assert model.bias_g.below is None and model.scale_factor.below is None and model.bias_g.drift_per_s is None
    value, sigma = model.bias_g.above
    assert abs(value - m.lambda_above_g_per_c) < 4 * sigma
    html = render_tumble_report(session, r, points, model, title="one side")
    assert html.count("not separable by this session") == 4  # lambda_T2, k0D, beta_T2, gamma_T2
