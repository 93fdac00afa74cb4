"""Tm of the closed-form twin against brute-force integration of the rate (first passage).

The reference integrates w_out(t) evaluated directly from the rate model
(station.twin.inputs, not the Fourier series) by adaptive quadrature, then
scans the last periods in steps of T/64 and solves the first passage with
brentq. Physics.md asks Tm to better than 1e-9 relative: that is the tolerance.
"""

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from station.twin.config import NoiseModel, TwinConfig
from station.twin.inputs import instrument_inputs, instrument_rate_radps
from station.twin.measurement import simulate_point
from station.twin.plan import PointSpec
from station.twin.precession import PrecessionWindow, periodic_rate


def brute_force_first_passage(theta, f, gamma0, cfg, target):
    """First passage by adaptive quadrature of the rate model, split where aI changes sign.

    aI |aI| has a kink where aI = 0 (a > 1), so each panel is integrated by
    scipy's quad with those phases as break points (~1e-15 relative per period).
    """
    w = 2 * math.pi * f
    T = 1 / f

    def rate(t):
        return float(instrument_rate_radps(theta, w * t + gamma0, w, cfg))

    probe = np.linspace(0.0, T, 4097)
    a_i = instrument_inputs(theta, w * probe + gamma0, w, cfg)[0]
    flips = np.flatnonzero(np.sign(a_i[:-1]) != np.sign(a_i[1:]))
    kinks = [
        brentq(lambda t: float(instrument_inputs(theta, w * t + gamma0, w, cfg)[0]), probe[i], probe[i + 1], xtol=1e-16)
        for i in flips
    ]

    def integral(a, b):  # a, b within one period shifted by k T; break at the kinks
        k = math.floor(a / T)
        pts = [x + k * T for x in kinks if a < x + k * T < b] + [
            x + (k + 1) * T for x in kinks if a < x + (k + 1) * T < b
        ]
        val, _ = quad(rate, a, b, points=pts or None, epsabs=1e-15, epsrel=1e-14, limit=200)
        return val

    per_period = integral(0.0, T)  # the rate is periodic: every whole period adds the same angle
    sign = math.copysign(1.0, per_period)
    n_safe = int((target - 0.5) / abs(per_period))  # |phi| swings by < 0.5 rad within a period
    t_safe, phi_safe = n_safe * T, n_safe * per_period
    step = T / 64

    acc, prev = phi_safe, t_safe
    for i in range(1, 200 * 64):
        t = t_safe + i * step
        before = acc  # phi(prev): the passage's step is solved from there, not summed again from t_safe
        acc += integral(prev, t)
        if sign * acc - target >= 0:
            return brentq(lambda x, a=prev, p=before: sign * (p + integral(a, x)) - target, prev, t, xtol=1e-13,
                          rtol=1e-15)  # fmt: skip
        prev = t
    raise AssertionError("no passage found")


EFFECT_CASES = [
    ("nominal", {}),
    ("waveform_fundamental", {"z0": -1.299e-4, "z1": 3.2e-6, "Zc1": 2e-5}),
    ("waveform_harmonics", {"Zs2": 2.4e-6, "Zc2": -4.2e-6, "Zs3": 1e-6}),
    ("parasitic_rotation", {"ax0": 5e-5, "axs1": -4.5e-6, "axc1": 9e-7}),
    ("lateral_resonance", {"L0": 2e-3, "fr": 25.0, "Q": 8.0, "phiL": 0.3, "kx": 1e-5}),
    ("odd_quadratic", {"koq": 3e-6}),
    ("cross_coupling", {"kip": 4e-6}),
    ("index_harmonics", {"c1": 2e-5, "s2": -1e-5}),
    ("mount_misalignment", {"dtheta_mount": 4e-5}),
]


@pytest.mark.parametrize(("effect", "params"), EFFECT_CASES, ids=[c[0] for c in EFFECT_CASES])
@pytest.mark.parametrize(("theta_deg", "f_hz"), [(0.0, 10.0), (144.0, 8.0), (252.0, 9.0)])
def test_tm_matches_brute_force_first_passage(effect, params, theta_deg, f_hz):
    cfg = TwinConfig()
    if effect != "nominal":
        cfg = cfg.with_effect(effect, **params)
    theta = math.radians(theta_deg)
    gamma0 = 1.234
    # 5 revolutions keep the brute force affordable; every step of the algorithm is the same as for 50.
    target = 2 * math.pi * 5
    window = PrecessionWindow(periodic_rate(theta, f_hz, cfg), 2 * math.pi * f_hz, gamma0)
    tm = window.first_passage_s(target)
    ref = brute_force_first_passage(theta, f_hz, gamma0, cfg, target)
    assert tm == pytest.approx(ref, rel=1e-9)


def test_first_passage_is_first_and_exact():
    cfg = TwinConfig()
    window = PrecessionWindow(periodic_rate(0.0, 10.0, cfg), 2 * math.pi * 10, 2.0)
    target = 2 * math.pi * 50
    roots = window.crossings_s(target, first_only=False)
    assert len(roots) >= 3  # a > 1: |phi| crosses the target several times near the end
    assert roots[0] == window.first_passage_s(target)
    t = np.linspace(0, roots[0], 200_001)[:-1]
    assert np.all(np.abs(window.phi_rad(t)) < target)
    assert abs(float(window.phi_rad(roots[0])) - target) < 1e-12 * target


def test_static_tm_is_closed_form():
    cfg = TwinConfig(earth_rate_on=False)
    k = cfg.instrument
    rate = k.k0 + k.kz + k.kzz + k.ky * 0 + k.k3
    sp = simulate_point(
        PointSpec(0.0, 0.0),
        cfg.__class__(earth_rate_on=False, noise=NoiseModel(timer_tick_s=0)),
        np.random.default_rng(0),
    )
    assert sp.record.Tm_s == pytest.approx(2 * math.pi * 50 / rate, rel=1e-14)
