"""Seed 003's design analysis and identifiability, on the pure functions (no station): sequences, test time,
uncertainty factors, ES(n), static-only identifiability, self-alignment (eqs. 55-56), and why the 4-pose
method needs its second setup."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from drivers.second_instrument.emulator import static_rates_radps
from procedures.multiposition.alignment import horizontal_axis_alignment
from procedures.multiposition.design import efficiency_sensitivity, total_test_time_s, uncertainty_factors
from procedures.multiposition.four_pose import PoseWindow, fit_four_pose
from procedures.multiposition.lsq import solve
from procedures.multiposition.sequences import HEAD_COUNTS_PER_DEG, sequence_deg
from procedures.multiposition.static_model import MODELS
from station.least_squares import FitError
from station.session import StationInfo
from station.twin.config import TwinConfig
from station.twin.fixture import POSES_DEG, SETUPS, mounted_twin
from station.twin.inputs import instrument_rate_radps

TWIN = TwinConfig.from_toml(Path(__file__).parents[2] / "config" / "twins" / "multiposition.toml")
STATION = StationInfo()
TERMS = MODELS["seed003"]
TEN_PI = 10 * math.pi  # seed 003's precession angle per position
K0, KZ = 4e-4, 0.55  # seed 003's simulation (5.2)
GRID_RAD = math.radians(1 / HEAD_COUNTS_PER_DEG)


@pytest.mark.parametrize("n", [10, 22, 23, 42])
def test_equal_acceleration_steps_are_equal_in_the_input(n) -> None:
    """Adjacent positions (round the circle) are 4/n apart along the path of aI = cos theta from +1 to -1 and
    back, to within an encoder count (for even n that is |delta aI| = 4/n everywhere; for odd n the step
    that turns at -1 folds); equal-angle positions are 360/n apart."""
    pos = np.array(sequence_deg("equal_acceleration", n))
    assert np.allclose(pos * HEAD_COUNTS_PER_DEG, np.round(pos * HEAD_COUNTS_PER_DEG), atol=1e-6)
    a = np.cos(np.radians(pos))
    path = np.where(pos <= 180.0, 1.0 - a, 3.0 + a)
    assert np.allclose(np.diff(np.append(path, path[0] + 4.0)), 4 / n, atol=GRID_RAD)
    if n % 2 == 0:
        assert np.allclose(np.abs(np.diff(np.append(a, a[0]))), 4 / n, atol=GRID_RAD)
    equal_angle = np.array(sequence_deg("equal_angle", n))
    assert np.allclose(np.diff(equal_angle), 360 / n, atol=1 / HEAD_COUNTS_PER_DEG)


def test_test_time_positions_with_the_input_axis_horizontal_cost_hours() -> None:
    """Seed 003 5.2: at 90 and 270 deg the rate is k0 and the earth rate alone, over 1000 min per 10 pi window;
    every n = 4k sequence has both and costs over 2500 min; otherwise equal angle is the cheaper (Fig. 7)."""
    for n in range(8, 61, 4):
        for scheme in ("equal_angle", "equal_acceleration"):
            assert 90.0 in sequence_deg(scheme, n) and 270.0 in sequence_deg(scheme, n)
            assert total_test_time_s(scheme, n, TEN_PI, K0, KZ, STATION) > 2500 * 60
    for n in (n for n in range(6, 61) if n % 4):
        t_angle = total_test_time_s("equal_angle", n, TEN_PI, K0, KZ, STATION)
        t_accel = total_test_time_s("equal_acceleration", n, TEN_PI, K0, KZ, STATION)
        assert t_angle < t_accel < 600 * 60, n


def test_equal_acceleration_favours_bias_and_scale_factor_equal_angle_the_second_order() -> None:
    """Seed 003 Table 2 (Fig. 4): d11, d22 smaller with equal acceleration, d33 with equal angle."""
    for n in range(9, 45):
        angle = uncertainty_factors(sequence_deg("equal_angle", n), TERMS)
        accel = uncertainty_factors(sequence_deg("equal_acceleration", n), TERMS)
        assert accel[0] < angle[0] and accel[1] < angle[1] and angle[2] < accel[2], n


def test_es_of_equal_angle_falls_below_002_beyond_31_positions() -> None:
    """Seed 003 Fig. 5: beyond n = 31 one more equal-angle position is worth little (< 0.02); equal
    acceleration keeps changing longer."""
    ns = np.arange(32, 51)
    angle = np.abs(efficiency_sensitivity("equal_angle", ns, TERMS))[1:]
    accel = np.abs(efficiency_sensitivity("equal_acceleration", ns, TERMS))[1:]
    assert np.all(angle < 0.02) and np.all(accel > angle)


def test_static_positions_cannot_separate_k0_from_ky_nor_kzz_from_ky() -> None:
    c = np.cos(np.radians(sequence_deg("equal_angle", 22)))
    X = np.column_stack([np.ones_like(c), c, c * c, 1 - c * c])
    y = X @ np.array([4e-4, 0.55, 5e-6, 3e-6])
    with pytest.raises(FitError, match="cannot separate k0, kzz, ky"):
        solve(lambda k: X @ k - y, lambda k: X, np.zeros(4), ("k0", "kz", "kzz", "ky"))
    assert MODELS["seed003"][0] == "k0+ky" and MODELS["seed003"][2] == "kzz-ky"


def test_self_alignment_eq_55_and_its_uncertainty_eq_56() -> None:
    """From the twin's rates at instrument angles 90 and 270 deg; the seed's uncertainties give eq. 56's value."""
    theta0 = 1.2e-4  # 25 arcsec
    twin = mounted_twin(TWIN.without_effect("index_harmonics"), theta0)
    w90, w270 = (float(instrument_rate_radps(math.radians(a), 0.0, 0.0, twin)) for a in (90, 270))
    a = horizontal_axis_alignment(w90, w270, STATION, kz_radps_per_g=KZ, sigma_rate_radps=6.8e-6,
                                  sigma_latitude_rad=math.radians(0.1), sigma_kz=1e-4)  # fmt: skip
    # Left out of eq. 55: the earth rate's cos(lam - theta0) ~ cos lam + theta0 sin lam, and koq sin^2 theta0.
    bound = (STATION.earth_rate_radps * math.sin(math.radians(STATION.latitude_deg)) * theta0 + 3e-6 * theta0**2) / KZ
    assert abs(a.dtheta_h_rad - theta0) < bound
    lam = math.radians(STATION.latitude_deg)
    s = math.sin(a.dtheta_h_rad)
    expected = math.sqrt(2 * (6.8e-6 / (2 * KZ)) ** 2 + (STATION.earth_rate_radps * math.sin(lam) *
                         math.radians(0.1) / KZ) ** 2 + (s * 1e-4 / KZ) ** 2)  # fmt: skip
    assert a.sigma_rad == pytest.approx(expected, rel=1e-6)
    assert 8e-6 < a.sigma_rad < 9.5e-6  # about 1.8 arcsec: well within the 30 arcsec the seed asks for


def _pose_windows(setups: tuple[int, ...], rng: np.random.Generator) -> list[PoseWindow]:
    """Both PIGAs' windows of the four-pose sequences with 2e-7 rad/s of noise each."""
    out = []
    for setup in setups:
        pose_a = SETUPS[setup][0]
        positions = sequence_deg("equal_acceleration" if setup == 1 else "equal_angle", 22)
        heads = np.radians((np.array(positions) - POSES_DEG[pose_a]) % 360)
        for inst, (pose, rates) in static_rates_radps(TWIN, setup, heads).items():
            noisy = rates + rng.normal(0.0, 2e-7, rates.size)
            out += [PoseWindow(inst, setup, pose, h, r) for h, r in zip(heads, noisy, strict=True)]
    return out


def test_the_second_setup_separates_what_one_setup_cannot() -> None:
    """In one setup each instrument's polynomial absorbs the first-order signature of s2 (kz and the odd
    terms), leaving only second-order traces; the second setup turns both instruments by 90 deg and the
    absorbed part changes sign. So s2's uncertainty from setup 1 alone is many times that from both."""
    rng = np.random.default_rng(5)
    one = fit_four_pose(_pose_windows((1,), rng), TERMS, 3, STATION)
    both = fit_four_pose(_pose_windows((1, 2), rng), TERMS, 3, STATION)
    s2 = 3
    assert one.harmonic_sigmas_rad[s2] > 5 * both.harmonic_sigmas_rad[s2]
    assert np.all(both.harmonic_sigmas_rad < 2e-7)
