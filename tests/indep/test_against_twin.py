"""The independent generator against the twin on common cases (the one file here that imports the twin).

Both solve the same physics.md window by different methods: the twin by a Fourier series of the
rate and its closed-form integral, tests/indep by Gauss-Legendre quadrature period by period and a
brentq first passage. Tolerance: Tm to 1e-12 relative (both are exact to rounding: phi ~ 300 rad is
held to ~1e-13 rad and the root to 1e-13 s, i.e. ~1e-15 relative; we reach <= 5e-16), far inside
the 1e-9 the issue asks. One exception, measured: with the kinked term koq aI|aI| at 10 Hz the twin's
Tm is 3.6e-11 relative off (its 256-phase FFT aliases the 1/k^3 tail of aI|aI|; our period integral
agrees with scipy's adaptive quad split at the kinks to 4e-15, see test_world), so odd_quadratic
gets 1e-10. t1 to 1e-12 s (both are (2 pi n - gamma0)/w + delta), t2 to the Tm tolerance times Tm,
Np exactly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from indep.world import Coefficients, Perturbation, Stamper, Window, window_timing
from station.twin.config import InstrumentCoefficients, NoiseModel, TwinConfig
from station.twin.effects import EFFECTS as TWIN_EFFECTS
from station.twin.measurement import simulate_point
from station.twin.plan import PointSpec

K = {"k0": -2.3e-4, "kz": 0.71, "kzz": -1.4e-5, "ky": 2.2e-5, "k3": -3.1e-6}  # far from seed 000
START_S = 1234.5
TM_REL_TOL = 1e-12
TM_REL_TOL_KINKED = 1e-10  # the twin's FFT aliasing of aI|aI| (module docstring)
T1_TOL_S = 1e-12

# name -> (twin parameters, our Coefficients overrides, our Perturbation fields)
_IDX = {f"{p}{k}": (1 + k) * 1e-5 * (1 if p == "c" else -1) for k in range(1, 5) for p in "cs"}
EFFECTS = {
    "none": ({}, {}, {}),
    "waveform_fundamental": (
        {"z0": 2e-5, "z1": 3e-7, "Zc1": -1.5e-5},
        {},
        {"z0_m": 2e-5, "z1_ms": 3e-7, "zc1_m": -1.5e-5},
    ),
    "waveform_harmonics": (
        {"Zs2": 5e-6, "Zc2": -4e-6, "Zs3": 3e-6, "Zc3": 2e-6},
        {},
        {"zs2_m": 5e-6, "zc2_m": -4e-6, "zs3_m": 3e-6, "zc3_m": 2e-6},
    ),
    "parasitic_rotation": (
        {"ax0": 5e-5, "axs1": -3e-5, "axc1": 4e-5},
        {},
        {"ax0_rad": 5e-5, "axs1_rad": -3e-5, "axc1_rad": 4e-5},
    ),
    "lateral_resonance": (
        {"L0": 0.008, "fr": 13.0, "Q": 7.0, "phiL": 0.7, "kx": 4e-5},
        {"kx": 4e-5},
        {"L0": 0.008, "fr_hz": 13.0, "Q": 7.0, "phiL_rad": 0.7},
    ),
    "odd_quadratic": ({"koq": 2e-5}, {"koq": 2e-5}, {}),
    "cross_coupling": ({"kip": -3e-5}, {"kip": -3e-5}, {}),
    "index_harmonics": (
        _IDX,
        {},
        {
            "idx_c_rad": tuple(_IDX[f"c{k}"] for k in range(1, 5)),
            "idx_s_rad": tuple(_IDX[f"s{k}"] for k in range(1, 5)),
        },
    ),
    "mount_misalignment": ({"dtheta_mount": 1e-4}, {}, {"mount_rad": 1e-4}),
    "bias_drift": ({"d": 3e-9}, {}, {"drift_radps_per_s": 3e-9}),
    "readhead_latency": ({"delta": 2e-4}, {}, {"latency_s": 2e-4}),
    "frequency_error": ({"eps_f": 3e-5}, {}, {"eps_f": 3e-5}),
}
POINTS = [(0, 0.0), (100, 0.0), (215, 0.0), (0, 10.0), (37, 7.3), (100, 2.5), (215, 10.0), (300, 8.0), (160, 4.4)]


def _pulses(position_deg: float) -> int:
    return 819200 if abs(math.cos(math.radians(position_deg))) > 0.3 else 40000


@pytest.mark.parametrize("name", list(EFFECTS))
def test_window_agrees_with_twin(name: str) -> None:
    twin_p, co_p, pe_p = EFFECTS[name]
    effects = {name: twin_p} if name != "none" else {}
    noise_free = NoiseModel(rate_noise_radps=0.0, timing_jitter_s=0.0, timer_tick_s=0.0, grating_noise_m=0.0)
    cfg = TwinConfig(instrument=InstrumentCoefficients(**K), effects=effects, noise=noise_free)
    co = Coefficients(**K, **co_p)
    pe = Perturbation(**pe_p)
    exact = Stamper(0.0, lambda n: np.zeros(n))
    tol = TM_REL_TOL_KINKED if name == "odd_quadratic" else TM_REL_TOL
    for k, (pos, f) in enumerate(POINTS):
        twin = simulate_point(PointSpec(pos, f, _pulses(pos)), cfg, np.random.default_rng(k), start_s=START_S)
        win = Window(co, pe, pos, f, twin.window.gamma0_rad, START_S)
        tm = win.first_passage(_pulses(pos))
        where = f"{name} at {pos} deg, {f} Hz"
        assert abs(tm - twin.true_Tm_s) <= tol * twin.true_Tm_s, f"{where}: Tm {tm!r} vs {twin.true_Tm_s!r}"
        assert math.copysign(1, twin.record.pulses) == win.mean_rate_sign(), where
        if f:
            ours = window_timing(win, tm, exact)
            assert ours.Np == twin.record.Np, where
            assert abs(ours.t1_s - twin.record.t1_s) <= T1_TOL_S, where
            assert abs(ours.t2_s - twin.record.t2_s) <= T1_TOL_S + tol * tm, where


def test_every_effect_of_the_twin_has_its_independent_counterpart_here() -> None:
    """A new effect module (station.twin.effects) is compared here too: its independent implementation is part of its
    tests (README, "Adding an effect")."""
    assert set(EFFECTS) - {"none"} == set(TWIN_EFFECTS)


def test_effects_change_tm_beyond_the_tolerance() -> None:
    """The comparison can fail: every effect moves Tm (or t1/t2) far beyond the tolerance at some point."""
    base = [Window(Coefficients(**K), Perturbation(), p, f, 1.0, START_S) for p, f in POINTS]
    base_tm = [w.first_passage(_pulses(w.theta_deg)) for w in base]
    for name, (_, co_p, pe_p) in EFFECTS.items():
        if name in ("none", "readhead_latency"):
            continue
        wins = [Window(Coefficients(**K, **co_p), Perturbation(**pe_p), p, f, 1.0, START_S) for p, f in POINTS]
        moved = max(abs(w.first_passage(_pulses(w.theta_deg)) / t - 1) for w, t in zip(wins, base_tm, strict=True))
        assert moved > 1e3 * TM_REL_TOL, name
