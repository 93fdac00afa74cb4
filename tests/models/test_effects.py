"""Every effect of physics.md's table is switchable by name and shows its own signature."""

import math

import numpy as np
import pytest

from station.twin.config import NoiseModel, TwinConfig, TwinConfigError
from station.twin.effects import EFFECTS
from station.twin.measurement import simulate_point
from station.twin.plan import PointSpec
from station.twin.precession import periodic_rate

EXACT = TwinConfig(noise=NoiseModel(timer_tick_s=0.0))
PHYSICS_TABLE = {
    "waveform_fundamental", "waveform_harmonics", "parasitic_rotation", "lateral_resonance", "odd_quadratic",
    "cross_coupling", "index_harmonics", "mount_misalignment", "bias_drift", "readhead_latency", "frequency_error",
}  # fmt: skip


def static_rate(cfg, theta_deg):
    return periodic_rate(math.radians(theta_deg), 0.0, cfg).c0_radps


def test_the_registry_is_the_physics_table():
    assert set(EFFECTS) == PHYSICS_TABLE


def test_unknown_effect_or_parameter_is_refused_with_what_is_allowed():
    with pytest.raises(TwinConfigError, match="unknown effect 'wobble'; known effects: waveform_fundamental"):
        EXACT.with_effect("wobble", x=1.0)
    with pytest.raises(TwinConfigError, match="has no parameter 'Zs9'; allowed: Zs2, Zc2, Zs3, Zc3"):
        EXACT.with_effect("waveform_harmonics", Zs9=1e-6)
    with pytest.raises(TwinConfigError, match="expected a finite number"):
        EXACT.with_effect("bias_drift", d=float("nan"))


def test_switching_an_effect_off_restores_the_nominal_twin():
    on = EXACT.with_effect("odd_quadratic", koq=1e-5)
    assert static_rate(on.without_effect("odd_quadratic"), 0) == static_rate(EXACT, 0)


def test_toml_round_trip(tmp_path):
    cfg = EXACT.with_effect("waveform_fundamental", z0=-1.299e-4, z1=3.2e-6).with_effect("frequency_error", eps_f=2e-6)
    path = tmp_path / "twin.toml"
    path.write_text(cfg.to_toml())
    assert TwinConfig.from_toml(path) == cfg


@pytest.mark.parametrize(
    ("effect", "params", "theta_deg", "expected_shift"),
    [
        # aI = 1 at 0 deg: koq aI|aI| = koq
        ("odd_quadratic", {"koq": 3e-6}, 0.0, 3e-6),
        # aI aP = cos sin = 1/2 at 45 deg
        ("cross_coupling", {"kip": 4e-6}, 45.0, 2e-6),
    ],
)
def test_instrument_terms_in_the_static_rate(effect, params, theta_deg, expected_shift):
    shift = static_rate(EXACT.with_effect(effect, **params), theta_deg) - static_rate(EXACT, theta_deg)
    assert shift == pytest.approx(expected_shift, rel=1e-9)


@pytest.mark.parametrize(
    ("effect", "params", "angle_rad"),
    [
        ("mount_misalignment", {"dtheta_mount": 5e-5}, 5e-5),
        (
            "index_harmonics",
            {"c1": 2e-5, "s2": 1e-5},
            2e-5 * math.cos(math.radians(60)) + 1e-5 * math.sin(math.radians(120)),
        ),
        # at rest the crank sits at psi = 0: alpha_x = ax0 + axc1
        ("parasitic_rotation", {"ax0": 3e-5, "axs1": 7e-6, "axc1": 1e-5}, 4e-5),
    ],
)
def test_angle_effects_tilt_the_static_input(effect, params, angle_rad):
    theta = 60.0
    shifted = static_rate(EXACT.with_effect(effect, **params), theta)
    rotated = static_rate(EXACT, theta + math.degrees(angle_rad))
    assert shifted == pytest.approx(rotated, abs=1e-15)


def test_frequency_error_breaks_the_period_identity_by_eps_np_t():
    eps = 2e-5
    p = simulate_point(
        PointSpec(0.0, 10.0), EXACT.with_effect("frequency_error", eps_f=eps), np.random.default_rng(1)
    ).record
    T = 0.1
    mismatch = p.t1_s + p.Np * T - p.Tm_s - p.t2_s
    assert mismatch == pytest.approx(p.Np * T * eps / (1 + eps), rel=1e-6)


def test_readhead_latency_delays_t1_and_t2():
    delta = 3e-4
    nominal = simulate_point(PointSpec(36.0, 9.0), EXACT, np.random.default_rng(2)).record
    late = simulate_point(
        PointSpec(36.0, 9.0), EXACT.with_effect("readhead_latency", delta=delta), np.random.default_rng(2)
    ).record
    assert late.Tm_s == nominal.Tm_s
    assert late.t1_s - nominal.t1_s == pytest.approx(delta, abs=1e-12)
    assert late.t2_s - nominal.t2_s == pytest.approx(delta, abs=1e-12)


def test_bias_drift_moves_the_rate_with_session_time():
    d = 1e-10
    cfg = EXACT.with_effect("bias_drift", d=d)
    start = 20_000.0
    p0 = simulate_point(PointSpec(0.0, 0.0), EXACT, np.random.default_rng(0), start_s=start).record
    p1 = simulate_point(PointSpec(0.0, 0.0), cfg, np.random.default_rng(0), start_s=start).record
    shift = p1.measured_rate_radps(16384) - p0.measured_rate_radps(16384)
    assert shift == pytest.approx(d * (start + p1.Tm_s / 2), rel=1e-6)  # the window mean of k0 + d t


def test_lateral_resonance_adds_kx_times_the_mean_square_lateral_input():
    p = {"L0": 2e-3, "fr": 25.0, "Q": 8.0, "phiL": 0.3, "kx": 1e-5}
    f = 10.0
    cfg = EXACT.with_effect("lateral_resonance", **p)
    shift = periodic_rate(0.0, f, cfg).c0_radps - periodic_rate(0.0, f, EXACT).c0_radps
    r = f / p["fr"]
    L = p["L0"] / math.sqrt((1 - r * r) ** 2 + (r / p["Q"]) ** 2)
    a_lat = L * cfg.station.A0_m * (2 * math.pi * f) ** 2 / cfg.station.g_mps2
    assert shift == pytest.approx(p["kx"] * a_lat**2 / 2, rel=1e-9)  # <sin^2> = 1/2 over a period
    assert static_rate(cfg, 0.0) == static_rate(EXACT, 0.0)  # no lateral motion at rest


def test_waveform_fundamental_scales_the_vibration_amplitude():
    z0, z1, f = -1.299e-4, 3.2e-6, 10.0
    w = 2 * math.pi * f
    cfg = EXACT.with_effect("waveform_fundamental", z0=z0, z1=z1)
    # kzz-like terms grow with amplitude^2: compare with a twin whose A0 includes Zs1 (physics.md z(t)).
    from dataclasses import replace

    bigger = replace(EXACT, station=replace(EXACT.station, A0_m=EXACT.station.A0_m + z0 + z1 * w))
    assert periodic_rate(0.0, f, cfg).c0_radps == pytest.approx(periodic_rate(0.0, f, bigger).c0_radps, rel=1e-14)
