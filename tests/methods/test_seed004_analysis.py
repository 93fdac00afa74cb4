"""Seed 004's analysis on its own: eqs. 10, 21 and 22 as pure functions, the spline minimum and its sigmas,
the per-offset calibration on simulated sessions, and the design check that runs before anything moves."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from procedures.nonlinear_suppression import analysis as a
from station.least_squares import FitError
from station.session import StationInfo
from station.twin import nonlinear_error as ne
from station.twin.config import default_twin
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session

pytestmark = pytest.mark.timeout(60)

KZ = 0.56
OFFSETS = np.round(np.arange(-5.0, 5.01, 0.5), 1)  # seed 004 section 5.1


def _true_k2(offsets_arcsec, model: ne.FloatModel | None = None) -> np.ndarray:
    model = model or ne.FloatModel.seed004(KZ)
    return model.kzz_radps_per_g2(np.asarray(offsets_arcsec) * ne.ARCSEC_RAD, KZ) / KZ


def test_eq21_inverts_eq10_and_eq22_gives_the_seeds_mass() -> None:
    j = 6.6e-8
    assert ne.inertia_from_quadratic(ne.quadratic_from_inertia(j, KZ, 0.1), KZ, 0.1) == pytest.approx(j)
    # the seed: 3.7e-7/g0 at the best offset -> 77.8 mg at each point (r_f chosen for that, H = 0.1 kg m^2/s)
    j_seed = ne.inertia_from_quadratic(3.7e-7 * KZ, KZ, ne.ANGULAR_MOMENTUM_KGM2PS)
    assert ne.removed_mass_kg(j_seed, ne.END_RADIUS_M) * 1e6 == pytest.approx(77.8, abs=0.05)
    # the removal takes away exactly what eq. 22 asked for, at any angle
    for angle in (math.radians(30), math.pi / 4):
        m = ne.removed_mass_kg(j_seed, 0.02, angle)
        assert ne.removal_inertia_product_kgm2(m, 0.02, angle) == pytest.approx(j_seed)
    assert ne.removed_mass_kg(j_seed, 0.02, math.radians(30)) > ne.removed_mass_kg(j_seed, 0.02)  # 45 deg is least


def test_spline_and_line_search_on_the_twins_curve() -> None:
    k2 = _true_k2(OFFSETS)
    best, k2_min = a.spline_minimum(OFFSETS, k2)
    # the seed reads -0.85" and 3.7e-7/g0; a 0.5" grid cannot resolve the curve's 0.17" wide bottom, so the
    # spline's minimum sits a little off and high: within 0.1" and 30 %
    assert abs(best - ne.SEED004_BEST_OFFSET_ARCSEC) < 0.1
    assert 3.7e-7 <= k2_min < 1.3 * 3.7e-7
    assert k2_min < k2.min()  # below the lowest calibration, as the seed found (3.7e-7 < 4.3e-7)


def test_sweep_fit_sigmas_describe_the_scatter_of_repeated_sweeps() -> None:
    """The Monte Carlo sigmas of one fit against how far 30 independent sweeps scatter. The sampling error of
    a standard deviation from 30 sweeps is 13 % (1 / sqrt(2 x 29)); K2's sigma must match within 35 %. The best
    offset's sigma is conservative by design (redrawing around noisy calibrations roughens the curve's narrow
    bottom a second time: about 1.3 x the scatter here): it must not be optimistic by more than 35 % nor
    conservative by more than a factor of 2."""
    k2 = _true_k2(OFFSETS)
    sigma = np.full(OFFSETS.size, 8e-8)
    rng = np.random.default_rng(7)
    fits = [a.fit_sweep(OFFSETS, k2 + sigma * rng.standard_normal(OFFSETS.size), sigma, 100) for _ in range(30)]
    best = np.array([f.best_offset_arcsec for f in fits])
    k2_min = np.array([f.k2_min_per_g for f in fits])
    assert np.mean([f.sigma_k2_min_per_g for f in fits]) == pytest.approx(k2_min.std(ddof=1), rel=0.35)
    assert 0.65 < np.mean([f.sigma_best_offset_arcsec for f in fits]) / best.std(ddof=1) < 2.0
    assert fits[0].sample_best_offset_arcsec in OFFSETS


def test_sweep_fit_refuses_too_few_or_repeated_offsets() -> None:
    with pytest.raises(FitError, match="at least 4 distinct offsets"):
        a.fit_sweep([0.0, 1.0, 2.0], [1e-6, 2e-6, 3e-6], [1e-8] * 3)
    with pytest.raises(FitError, match="at least 4 distinct offsets"):
        a.fit_sweep([0.0, 1.0, 1.0, 2.0], [1e-6, 2e-6, 2e-6, 3e-6], [1e-8] * 4)


def test_calibrations_find_the_twins_kzz_within_their_pooled_sigma() -> None:
    """The per-offset calibration (seed 000 integral precession, 0/180/60 deg at 8/9/10 Hz, 60 s windows) on
    12 sessions, with the residual sigma pooled over them (60 degrees of freedom): |error| / sigma has an rms
    near 1; below 1.6, which chi^2 with 12 degrees of freedom exceeds with probability under 1 %."""
    twin = default_twin()
    truth = 0.56 * 1.9e-6
    twin = replace(twin, instrument=replace(twin.instrument, kzz=truth))
    plan = multiposition_plan([0.0, 180.0, 60.0], [8.0, 9.0, 10.0], 60.0)
    own = []
    for seed in range(12):
        s = simulate_session(plan, twin, seed)
        own.append(a.calibrate(s.station, s.points, f"S{seed + 1:02d}", a.SWEEP, 0.0))
    cals = a.pooled(own)
    assert {c.noise_radps for c in cals} == {cals[0].noise_radps} and all(c.dof == 5 for c in own)
    assert cals[0].noise_radps == pytest.approx(np.sqrt(np.mean([c.sigma_residual_radps**2 for c in own])))
    z = [(c.kzz - truth) / c.sigma_kzz for c in cals]
    assert np.sqrt(np.mean(np.square(z))) < 1.6
    c = cals[0]
    assert c.k2_per_g == pytest.approx(c.kzz / c.kz) and c.sigma_k2_per_g == pytest.approx(c.sigma_kzz / c.kz, rel=0.05)
    assert c.sigma_kzz < 1e-7  # resolves the curve: 1e-7 rad/s/g^2 is 1.8e-7/g0


def test_design_check_names_what_cannot_be_identified() -> None:
    station = StationInfo()
    assert a.design_defect(station, [0, 180, 60], [8, 9, 10]) is None
    assert "vibration points" in a.design_defect(station, [0, 180], [8, 10])
    assert "separate kzz, ky and k3" in a.design_defect(station, [0, 120, 240], [8, 9, 10])
