"""The window solver against independent numerics and physics.md's closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from indep.effects import window_means
from indep.world import (
    A0_M,
    G_MPS2,
    PULSE_RAD,
    Coefficients,
    Perturbation,
    Stamper,
    Window,
    pulse_edges,
    window_timing,
)

CO = Coefficients(k0=3.1e-4, kz=0.42, kzz=1.7e-5, ky=-8e-6, k3=2.4e-6)
EXACT = Stamper(0.0, lambda n: np.zeros(n))
LAT = math.radians(39.94)
W_IE = 7.292115e-5


@pytest.mark.parametrize(
    ("co", "pe"),
    [
        (CO, Perturbation()),
        (Coefficients(**{**CO.as_dict(), "koq": 2e-5, "kz_asym": 3e-4}), Perturbation()),  # kinks at aI = 0
        (CO, Perturbation(zs2_m=8e-6, zc3_m=-5e-6, axs1_rad=4e-5, L0=0.01, fr_hz=12.0, phiL_rad=1.0)),
    ],
)
def test_period_integral_matches_adaptive_quadrature(co: Coefficients, pe: Perturbation) -> None:
    """Gauss-Legendre per panel (kinks as panel edges) vs QUADPACK split at the kinks: 1e-13 relative."""
    for theta, f in [(20.0, 10.0), (135.0, 6.3), (250.0, 1.5)]:
        w = Window(co, pe, theta, f, 0.9, 0.0)
        kinks = list(_aI_zeros(w))

        def rate(t: float, w: Window = w) -> float:
            return float(w.rate_periodic(np.array([t]))[0])

        ref, err = quad(rate, 0.0, w.T, points=kinks or None, epsabs=1e-17, epsrel=1e-13, limit=400)
        assert abs(w.phi_period - ref) <= 1e-13 * abs(ref) + 2 * err, (theta, f)


def _aI_zeros(w: Window) -> list[float]:
    t = np.linspace(0.0, w.T, 20001)
    a = w.inputs(t)[0]
    i = np.nonzero(np.sign(a[:-1]) != np.sign(a[1:]))[0]
    return [brentq(lambda x: float(w.inputs(np.array([x]))[0][0]), t[k], t[k + 1], xtol=1e-15) for k in i]


@pytest.mark.parametrize(
    ("theta", "f", "gamma0"), [(0.0, 10.0, 0.3), (63.0, 7.7, 2.0), (200.0, 3.3, 5.1), (300.0, 1.2, 4.0)]
)
def test_first_passage_is_first_and_on_target(theta: float, f: float, gamma0: float) -> None:
    """|phi(Tm)| = target, and |phi| stays below the target everywhere before (dense scan of the last periods)."""
    w = Window(CO, Perturbation(), theta, f, gamma0, 50.0)
    pulses = 16384 * 12
    tm = w.first_passage(pulses)
    target = pulses * PULSE_RAD
    s = w.mean_rate_sign()
    assert abs(s * float(w.phi(np.array(tm))) - target) < 1e-11
    before = np.linspace(max(0.0, tm - 6 * w.T), tm, 30001)[:-1]
    assert np.all(s * w.phi(before) < target)
    assert s * float(w.rate(np.array(tm))) > 0  # reached on a rising flank
    # phi by quadrature against QUADPACK from 0 to an arbitrary time inside the window
    t_x = 0.37 * tm
    ref = quad(lambda t: float(w.rate(np.array([t]))[0]), 0.0, t_x, limit=20000, epsrel=1e-13)[0]
    assert abs(float(w.phi(np.array(t_x))) - ref) < 1e-9 * abs(ref)


@pytest.mark.parametrize(
    ("theta", "f", "gamma0"), [(0.0, 10.0, 0.3), (37.0, 8.0, 2.0), (140.0, 4.25, 5.1), (290.0, 1.5, 1.0)]
)
def test_window_means_match_closed_forms(theta: float, f: float, gamma0: float) -> None:
    """Measured rate 2 pi P / (16384 Tm) = the nominal model averaged with physics.md's <s>, <s^2>, <s^3>."""
    w = Window(CO, Perturbation(), theta, f, gamma0, 0.0)
    pulses = 16384 * 20
    tm = w.first_passage(pulses)
    tim = window_timing(w, tm, EXACT)
    s1, s2, s3 = window_means(f, tim.t1_s, tim.t2_s, tm)
    # the closed forms themselves against direct quadrature of sin^n w (t - t1) over [0, Tm]
    om = 2 * math.pi * f
    for n, closed in ((1, s1), (2, s2), (3, s3)):
        direct = quad(lambda t, n=n: math.sin(om * (t - tim.t1_s)) ** n, 0.0, tm, limit=50000, epsabs=1e-13)[0] / tm
        assert abs(direct - closed) < 1e-11, n
    a = A0_M * om**2 / G_MPS2
    th = math.radians(theta)
    c, sn = math.cos(th), math.sin(th)
    q2 = 1 - 2 * a * s1 + a * a * s2
    pred = (
        CO.k0
        + CO.kz * c * (1 - a * s1)
        + CO.kzz * c * c * q2
        + CO.ky * sn * sn * q2
        + CO.k3 * c**3 * (1 - 3 * a * s1 + 3 * a * a * s2 - a**3 * s3)
        - W_IE * math.sin(LAT - th)
    )
    measured = w.mean_rate_sign() * pulses * PULSE_RAD / tm
    assert abs(measured - pred) < 1e-12 * abs(pred)
    # the reference crossing that defines t1 is at psi = 0 mod 2 pi
    psi_t1 = w.psi(np.array(tim.t1_s))
    assert abs(math.remainder(float(psi_t1), 2 * math.pi)) < 1e-9


def test_period_identity_exact_without_effects_and_broken_by_frequency_error() -> None:
    """t1 + Np T - Tm - t2 = 0 (noise-free), = Np T eps/(1+eps) with a frequency error (physics.md)."""
    for eps in (0.0, 4e-5, -2e-4):
        for theta, f in [(10.0, 9.5), (170.0, 2.0)]:
            w = Window(CO, Perturbation(eps_f=eps), theta, f, 1.7, 0.0)
            tm = w.first_passage(16384 * 30)
            tim = window_timing(w, tm, EXACT)
            r = tim.t1_s + tim.Np / f - tm - tim.t2_s
            assert abs(r - tim.Np / f * eps / (1 + eps)) < 1e-10, (eps, theta, f)


def test_latency_shifts_t1_and_t2_but_keeps_the_identity() -> None:
    delta = 3e-4
    w0 = Window(CO, Perturbation(), 30.0, 6.0, 2.5, 0.0)
    w1 = Window(CO, Perturbation(latency_s=delta), 30.0, 6.0, 2.5, 0.0)
    tm = w0.first_passage(16384 * 10)
    a, b = window_timing(w0, tm, EXACT), window_timing(w1, tm, EXACT)
    assert math.isclose(b.t1_s - a.t1_s, delta, abs_tol=1e-12) and math.isclose(b.t2_s - a.t2_s, delta, abs_tol=1e-12)
    assert abs(b.t1_s + b.Np / 6.0 - tm - b.t2_s) < 1e-10


@pytest.mark.parametrize(("theta", "f"), [(25.0, 10.0), (120.0, 3.5), (0.0, 0.0)])
def test_pulse_edges_consistent_with_phi_and_tm(theta: float, f: float) -> None:
    """Each edge sits on its level; up minus down edges count the levels crossed; the P-th edge is Tm."""
    w = Window(CO, Perturbation(), theta, f, 0.8, 10.0)
    pulses = 16384 * 3
    tm = w.first_passage(pulses)
    t_a = max(0.0, tm - 1.5)
    t, d = pulse_edges(w, t_a, tm)
    lev = w.phi(t) / PULSE_RAD
    assert np.all(np.abs(lev - np.round(lev)) < 1e-9)
    assert np.all(np.diff(t) >= 0)
    # direction: up edges where phi increases (rate > 0), down where it decreases
    r = w.rate(t)
    assert np.all((d > 0) == (r > 0))
    s = w.mean_rate_sign()
    start_level = math.floor(s * float(w.phi(np.array(t_a))) / PULSE_RAD)
    assert start_level + int(np.sum(s * d)) == pulses
    assert abs(t[-1] - tm) < 1e-9 and s * d[-1] > 0
    if f:  # at 10 Hz the rate reverses each period: edges in both directions
        assert (np.sum(d < 0) > 0) == (A0_M * (2 * math.pi * f) ** 2 / G_MPS2 > 1.05)
