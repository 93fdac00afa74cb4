"""GUM budgets of seeds 001-004 (issue 15): Type B sensitivities against an independent finite difference, the
results JSON's GUM fields, and a small seeded Monte Carlo of each method's coverage.

Independent finite differences: the data are made again with the input changed (the twin's head turned, the
IMU's accelerometers scaled, the site moved) and identified as they come; the budget's refit instead corrects
the same data for a known input, so its sensitivity is minus the data's (for the inputs the identification
itself uses, latitude and g, the identification is re-run on unchanged data and the signs agree).

Coverage bands: per coefficient the count of sessions with |k_hat - k| <= U is binomial(N, 0.95) if U is a
95 % interval; the tests accept it within 3.29 binomial standard deviations (two-sided 99.9 %), so a correct
budget fails one coefficient's check in 1000. The Monte Carlo draws every Type B input from the distribution the
references state (rectangular where they say so), which the budget's coverage factor takes into account
(procedures.common.uncertainty: Student's t times the shape factor; BENCHMARKS.md, issue 15).
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from procedures.common.references import load_references
from procedures.common.uncertainty import COVERAGE_PROBABILITY
from station.session import Measurement, Session, StationInfo

ROOT = Path(__file__).parents[2]
sys.path.insert(0, str(ROOT / "bench"))
import bench_mc_methods as mc  # noqa: E402  (the bench's session makers: one code for the bench and the test)

REFS = load_references()
BIAS_TOLERANCE = 0.05  # seed 002's gyro-bias rows: B's north shift only; the alignments' share measured below 1 %
COEFFICIENT_FIELDS = {"value", "unit", "standard_uncertainty", "effective_dof", "coverage_factor",
                      "coverage_probability", "expanded_uncertainty"}  # fmt: skip
ROW_FIELDS = {"source", "type", "value", "standard_uncertainty", "sensitivity", "contribution"}


def coverage_band(n: int) -> tuple[float, float]:
    """Two-sided 99.9 % band of a binomial(n, 0.95) fraction (normal approximation, z = 3.29)."""
    half = 3.29 * math.sqrt(COVERAGE_PROBABILITY * (1 - COVERAGE_PROBABILITY) / n)
    return COVERAGE_PROBABILITY - half, min(1.0, COVERAGE_PROBABILITY + half)


def row(budget, label: str):
    return next(s for s in budget.sources if s.source.startswith(label))


def assert_gum_json(doc: dict, names) -> None:
    """The issue's item 2: per coefficient value .. expanded_uncertainty, covariance {names, matrix}, budget rows."""
    for n in names:
        assert set(doc["coefficients"][n]) >= COEFFICIENT_FIELDS, n
        c = doc["coefficients"][n]
        assert c["expanded_uncertainty"] == pytest.approx(c["coverage_factor"] * c["standard_uncertainty"])
    assert list(doc["covariance"]["names"]) == list(names)
    assert np.shape(doc["covariance"]["matrix"]) == (len(names), len(names))
    assert {r["type"] for r in doc["budget"]} == {"A", "B"}
    for r in doc["budget"]:
        assert set(r) >= ROW_FIELDS and set(r["sensitivity"]) == set(names)


# ---------------------------------------------------------------- seed 001


def _tumble(**inputs):
    from procedures.tumble.analysis import analyse_tumble
    from procedures.tumble.tumble_session import tumble_session
    from station.twin.pendulous_accelerometer import AccelerometerModel

    session, _ = tumble_session(AccelerometerModel(), [20.0], 3, 8e-6, np.random.default_rng(7), **inputs)
    return analyse_tumble(session, 20.0)[1][0]


def test_seed001_type_b_rows_match_tumbles_made_again_with_the_input() -> None:
    """Noise-free tumbles with the head turned by +-h at 45 deg (and at 90 deg), the voltmeter's gain and offset
    at +-h: -(K(+h) - K(-h)) / 2h is each row's sensitivity. Eq. 1 is smooth in theta, so the central difference
    differs from the refit's by O(h^2 Y''') / Y': below 1e-6 of the largest sensitivity at h = 1e-5 rad; 1e-4
    allowed (the refit's own step is u, 1.2e-5 rad)."""
    p = _tumble()
    cases = {
        "index head angle error at 45 deg": ("head_error_rad", 1, 1e-5),
        "index head angle error at 90 deg": ("head_error_rad", 2, 1e-5),
        "voltmeter gain": ("voltmeter_gain", None, 1e-5),
        "voltmeter offset": ("voltmeter_offset_v", None, 1e-5),
    }
    for label, (key, j, h) in cases.items():

        def value(x: float, key: str = key, j: int | None = j):
            if j is None:
                return {key: x}
            e = np.zeros(8)
            e[j] = x
            return {key: e}

        independent = -(_tumble(**value(h)).cf - _tumble(**value(-h)).cf) / (2 * h)
        c = row(p.budget, label).sensitivity
        assert np.max(np.abs(c)) > 0, label
        np.testing.assert_allclose(c, independent, rtol=0, atol=1e-4 * np.max(np.abs(independent)), err_msg=label)
    # J = 9 is J = 1 after a full turn: one input for both
    assert row(p.budget, "index head angle error at 0 deg (J = 1, 9)").source.endswith("(J = 1, 9)")


def test_seed001_json_carries_the_budget_of_eq6_and_of_the_error_model() -> None:
    from procedures.tumble.analysis import ERROR_NAMES
    from station.twin.pendulous_accelerometer import CF_NAMES

    doc = _tumble().to_json()
    cf, errors = doc["gum_cf"], doc["gum_errors"]
    assert_gum_json({"coefficients": doc["coefficients"], **cf}, CF_NAMES)
    assert_gum_json({"coefficients": doc["coefficients"], **errors}, ERROR_NAMES)
    assert len([r for r in cf["budget"] if r["type"] == "B"]) == 10  # 8 head angles, gain, offset


def test_seed001_report_shows_the_budget() -> None:
    from procedures.tumble.analysis import analyse_tumble
    from procedures.tumble.report import render_tumble_report
    from procedures.tumble.tumble_session import tumble_session
    from station.twin.pendulous_accelerometer import AccelerometerModel

    session, _ = tumble_session(AccelerometerModel(), [20.0, 80.0], 3, 8e-6, np.random.default_rng(1))
    html = render_tumble_report(session, *analyse_tumble(session, 20.0), title="t")
    assert html.count("Uncertainty budget at") == 2 and "voltmeter offset" in html


@pytest.mark.slow
def test_seed001_monte_carlo_coverage() -> None:
    n = 150
    tally = mc.seed001(n, 11, REFS)
    lo, hi = coverage_band(n)
    cover = np.mean(tally.covered, axis=0)
    assert np.all((lo <= cover) & (cover <= hi)), dict(zip(tally.names, cover, strict=True))


# ---------------------------------------------------------------- seed 002


@pytest.fixture(scope="module")
def imu_runs():
    """Nine calibration runs (60 s at rest, 30 s of vibration: the test's, not the seed's) and the site."""
    from procedures.rlg_g_sensitivity.vibration_run import simulate_run
    from station.constants import EARTH_RATE_RADPS, G_MPS2, LATITUDE_DEG
    from station.twin.fixture_poses import CALIBRATION_POSES, POSES
    from station.twin.shaker_motion import sine_drive
    from station.twin.strapdown_imu import Site, StrapdownImuTwin

    site = Site(G_MPS2, EARTH_RATE_RADPS, math.radians(LATITUDE_DEG))
    rng = np.random.default_rng(3)
    drive = sine_drive(20.0, 1.5, G_MPS2)
    runs = [(k, simulate_run(StrapdownImuTwin(), site, POSES[k], drive, rate_hz=200.0, align_s=60.0, vibrate_s=30.0,
                             ramp_s=2.0, rng=rng)) for k in CALIBRATION_POSES]  # fmt: skip
    return runs, site


def _observe(runs, site, accel: np.ndarray | None = None, bias_radps: np.ndarray | None = None):
    """Each run reduced (eqs. 17-22) with its accelerometers scaled by 1 + accel and a gyro bias added."""
    from procedures.rlg_g_sensitivity.analysis import RunRecord, observation_values, observe_run

    accel = np.zeros(3) if accel is None else accel
    bias = np.zeros(3) if bias_radps is None else bias_radps
    out = []
    for _, r in runs:
        record = RunRecord.from_times(r.dtheta + bias * r.dt_s, r.dv * (1 + accel), r.dt_s, 0.0, r.t0_s, r.tk_s)
        out.append(observation_values(observe_run(record, site)) | {"align_s": record.i0 * record.dt_s})
    return out


def _tau(values) -> np.ndarray:
    """Eq. 21 as the session's analysis weights it (procedures.rlg_g_sensitivity.analysis.run_weights), in arcsec/g."""
    from procedures.rlg_g_sensitivity.analysis import estimate_flexure, run_weights
    from station.twin.strapdown_imu import ARCSEC_PER_G

    A, B = np.vstack([v["A"] for v in values]), np.concatenate([v["B"] for v in values])
    return estimate_flexure(A, B, run_weights(values)).values / ARCSEC_PER_G


def test_seed002_type_b_rows_match_runs_reduced_again(imu_runs) -> None:
    """Accelerometer k scaled by 1 +- h in the increments, each run reduced again (alignments, attitudes, eqs.
    17-22): -(tau(+h) - tau(-h)) / 2h. The budget scales A's columns only and leaves out the alignments' share
    (their level frame turns by h times the off-vertical force, and the stored observations keep only its
    horizontal rows): measured on these poses at most 17 % of the largest sensitivity, so 20 % is allowed
    (a contribution of 1e-4 arcsec/g at 50 ppm, against 0.05-0.1 arcsec/g of Type A). Latitude: the runs
    reduced at lam +- 0.5 deg; the budget's first order in the attitude error (1e-4 rad) allows 2 %."""
    from procedures.rlg_g_sensitivity.budget import flexure_budget

    runs, site = imu_runs
    budget = flexure_budget(_observe(runs, site), site, REFS)
    h = 1e-3
    for k, axis in enumerate("xyz"):
        e = np.zeros(3)
        e[k] = h
        independent = -(_tau(_observe(runs, site, e)) - _tau(_observe(runs, site, -e))) / (2 * h)
        c = row(budget, f"accelerometer {axis}").sensitivity
        assert np.max(np.abs(c)) > 0.1, axis
        np.testing.assert_allclose(c, independent, rtol=0, atol=0.20 * np.max(np.abs(independent)), err_msg=axis)
    h = 1e-7  # rad/s, 7 times the stated u: the reduction is linear in the bias
    for k, axis in enumerate("xyz"):
        b = np.zeros(3)
        b[k] = h
        independent = -(_tau(_observe(runs, site, bias_radps=b)) - _tau(_observe(runs, site, bias_radps=-b))) / (2 * h)
        c = row(budget, f"gyro {axis} residual bias").sensitivity
        assert np.max(np.abs(c)) > 0, axis
        np.testing.assert_allclose(c, independent, rtol=0, atol=BIAS_TOLERANCE * np.max(np.abs(independent)),
                                   err_msg=axis)  # fmt: skip
    d = math.radians(0.5)
    moved = [replace(site, latitude_rad=site.latitude_rad + s * d) for s in (1, -1)]
    independent = (_tau(_observe(runs, moved[0])) - _tau(_observe(runs, moved[1]))) / (2 * d)
    c = row(budget, "latitude").sensitivity
    np.testing.assert_allclose(c, independent, rtol=0, atol=0.02 * np.max(np.abs(independent)))
    assert np.max(np.abs(row(budget, "IMU sampling").sensitivity)) > 0.1  # A scales by 1 / (1 + e_t): c = -tau


def test_seed002_report_json_carries_the_budget(imu_runs) -> None:
    from procedures.rlg_g_sensitivity.report import analyse_session
    from station.twin.strapdown_imu import TAU_NAMES

    runs, site = imu_runs
    values = _observe(runs, site)
    station = replace(StationInfo(), latitude_deg=math.degrees(site.latitude_rad))
    ms = [Measurement(f"cal-{k}", "seed002_run", {**v, "role": "calibration", "pose": k, "rate_hz": 200,
                      "snippet_rate_radps": np.zeros((4, 3)).tolist(), "snippet_force_mps2": np.ones((4, 3)).tolist()})
          for (k, _), v in zip(runs, values, strict=True)]  # fmt: skip
    analysis = analyse_session(Session(station, [], measurements=ms))
    gum = analysis.results["flexure"]["gum"]
    assert_gum_json(gum, TAU_NAMES)
    assert "Uncertainty budget" in analysis.report_html


@pytest.mark.slow
def test_seed002_monte_carlo_coverage() -> None:
    n = 16
    tally = mc.seed002(n, 12, REFS, align_s=30.0, vibrate_s=15.0)
    lo, _ = coverage_band(n)
    cover = np.mean(tally.covered, axis=0)
    assert np.all(cover >= lo), dict(zip(tally.names, cover, strict=True))


# ---------------------------------------------------------------- seed 003


def _seed003_case(twin_changes=None, latitude_deg: float | None = None, exact: bool = False):
    """Noise-free four-pose windows and A's equal-angle calibration of the seed-003 twin (optionally changed)."""
    from drivers.second_instrument.emulator import static_rates_radps
    from procedures.multiposition.sequences import sequence_deg
    from station.twin.config import TwinConfig

    twin = TwinConfig.from_toml(ROOT / "config" / "twins" / "multiposition.toml")
    if exact:  # the model fits such data exactly: no head error, A's axis on the head zero
        twin = twin.without_effect("index_harmonics").with_effect("mount_misalignment", dtheta_mount=0.0)
    for effect, params in (twin_changes or {}).items():
        twin = twin.with_effect(effect, **params)
    if latitude_deg is not None:
        twin = replace(twin, station=replace(twin.station, latitude_deg=latitude_deg))
    windows = mc.four_pose_windows(twin, None, 0.0)
    cal = np.radians(sequence_deg("equal_angle", 22))
    return twin, windows, cal, static_rates_radps(twin, 1, cal)["A"][1]


def _seed003_fits(windows, cal, rates):
    from procedures.multiposition.four_pose import fit_four_pose
    from procedures.multiposition.static_model import MODELS, fit_static, with_angle_uncertainty
    from station.twin.fixture import pose_rad

    st, terms = StationInfo(), MODELS["seed003"]
    unc = fit_static(cal + pose_rad(1), rates, terms, st)
    fp = fit_four_pose(windows, terms, 3, st)
    angles = fp.instrument_angle_rad("A", 1, 1, cal)
    comp = fit_static(angles, rates, terms, st)
    total = with_angle_uncertainty(comp, angles, fp.angle_derivatives(cal), fp.angle_covariance("A", 1), st)
    return unc, fp, comp, total


def test_seed003_type_b_rows_match_the_twin_made_again_with_the_input() -> None:
    """Around data the static model fits exactly (the twin without head error, A's axis on the head zero):
    the head's harmonic s1, s2 at +- h, A's mount (the head zero's error) at +- h, the site's latitude at
    +- 0.01 deg put in the twin and identified as they come; minus the central difference is the row's
    sensitivity (compensated: the latitude through the four-pose and the calibration fits). Only where the
    residuals vanish do the two agree: the refit also turns the regressors against the residuals, which is
    the measurement model's own sensitivity. The fits are linear in the rates and the angles enter smoothly:
    1 % of the largest sensitivity allowed (second order in h = 1e-6 rad)."""
    from procedures.multiposition import budget as gum
    from station.twin.fixture import pose_rad

    _, windows, cal, rates = _seed003_case(exact=True)
    unc, fp, comp, total = _seed003_fits(windows, cal, rates)
    assert unc.sigma_residual < 1e-12
    tm = np.full(cal.size, 600.0)
    st = StationInfo()
    b_unc = gum.uncompensated_budget(unc, cal, cal + pose_rad(1), rates, tm, st, 3, 8e-6, REFS)
    b_comp = gum.compensated_budget(comp, total, fp, windows, 1, 1, cal, rates, tm, st, REFS)
    h = 1e-6
    cases = {f"angle-error harmonic {n}": [{"index_harmonics": {n: s * h}} for s in (1, -1)] for n in ("s1", "s2")}
    cases["head zero"] = [{"mount_misalignment": {"dtheta_mount": s * h}} for s in (1, -1)]
    for label, changes in cases.items():
        fits = [_seed003_fits(*_seed003_case(c, exact=True)[1:])[0] for c in changes]
        independent = -(fits[0].values - fits[1].values) / (2 * h)
        c = row(b_unc, label).sensitivity
        assert np.max(np.abs(c)) > 0, label
        np.testing.assert_allclose(c, independent, rtol=0, atol=0.01 * np.max(np.abs(independent)), err_msg=label)
    d = 0.01
    both = [_seed003_fits(*_seed003_case(latitude_deg=st.latitude_deg + s * d, exact=True)[1:]) for s in (1, -1)]
    for budget, which in ((b_unc, 0), (b_comp, 2)):
        independent = -(both[0][which].values - both[1][which].values) / (2 * d)
        c = row(budget, "latitude").sensitivity
        assert np.max(np.abs(c)) > 0
        np.testing.assert_allclose(c, independent, rtol=0, atol=0.01 * np.max(np.abs(independent)))


def test_seed003_json_carries_both_budgets() -> None:
    from procedures.multiposition import budget as gum
    from procedures.multiposition import gravity_field as gf
    from station.twin.fixture import pose_rad

    _, windows, cal, rates = _seed003_case()
    unc, fp, comp, total = _seed003_fits(windows, cal, rates)
    tm, st = np.full(cal.size, 600.0), StationInfo()
    budgets = {
        "uncompensated": gum.uncompensated_budget(unc, cal, cal + pose_rad(1), rates, tm, st, 3, 8e-6, REFS),
        "compensated_total": gum.compensated_budget(comp, total, fp, windows, 1, 1, cal, rates, tm, st, REFS),
    }
    doc = gf.Calibration("equal_angle", np.degrees(cal), tm, unc, comp, total, budgets).to_json()
    for name in budgets:
        assert_gum_json(doc[name], unc.names)
        assert doc[name]["type_b"] == gum.TYPE_B[name]
    assert "budget" in doc["compensated"]  # eq. 49 as the seed has it (Type A only) is kept beside


@pytest.mark.slow
def test_seed003_monte_carlo_coverage() -> None:
    n = 300
    tallies = mc.seed003(n, 13, REFS)
    lo, hi = coverage_band(n)
    for tally in tallies:
        cover = np.mean(tally.covered, axis=0)
        assert np.all((lo <= cover) & (cover <= hi)), dict(zip(tally.names, cover, strict=True))


# ---------------------------------------------------------------- seed 004


@pytest.fixture(scope="module")
def seed004_case():
    from procedures.nonlinear_suppression.analysis import AFTER_REMOVAL, AT_BEST, calibrate, pooled
    from station.twin.config import default_twin
    from station.twin.plan import multiposition_plan
    from station.twin.session_sim import simulate_session

    plan = multiposition_plan([0.0, 180.0, 60.0], [8.0, 9.0, 10.0], 560.0)
    s1, s2 = (simulate_session(plan, default_twin(), seed=s) for s in (41, 42))
    best, after = pooled([calibrate(s1.station, s1.points, "B", AT_BEST, 0.0),
                          calibrate(s2.station, s2.points, "A", AFTER_REMOVAL, 0.0)])  # fmt: skip
    return s1, s2, best, after


def test_seed004_type_b_rows_match_eqs_21_22_and_a_recalibration(seed004_case) -> None:
    """H and b: eqs. 21-22 give m = kzz H / kz^2 / (2 b^2 sin 2 theta), so dm/dH = m / H and dm/db = -2 m / b
    exactly (the refit's central difference at u is exact to (u/b)^2 = 2e-6): 1e-5 relative allowed. g: K2 of
    the calibration re-run (seed 004's own calibrate) with the station's g at +- u, against the row carried by
    the chain rule from seed 000's budget: 1 % allowed (both are central differences of one linear fit)."""
    from procedures.nonlinear_suppression.analysis import calibrate, correction
    from procedures.nonlinear_suppression.budget import suppression_budget

    s1, s2, best, after = seed004_case
    nominal = (0.1, 20.607, 45.0)
    budget = suppression_budget(s1.station, (s1.points, best), (s2.points, after), nominal, REFS, timer_rows=False)
    mass = budget.values[1]
    assert row(budget, "angular momentum").sensitivity[1] == pytest.approx(mass / nominal[0], rel=1e-5)
    assert row(budget, "radius b").sensitivity[1] == pytest.approx(-2 * mass / nominal[1], rel=1e-5)
    assert row(budget, "angle theta").sensitivity[1] == pytest.approx(0.0, abs=1e-3 * mass)  # sin 2 theta at 45 deg
    u_g = REFS["g_mps2"].standard_uncertainty
    cals = [calibrate(replace(s1.station, g_mps2=s1.station.g_mps2 + s * u_g), s1.points, "B", "best offset", 0.0)
            for s in (1, -1)]  # fmt: skip
    c = row(budget, "local gravity g").sensitivity
    independent = (cals[0].k2_per_g - cals[1].k2_per_g) / (2 * u_g)
    assert c[0] == pytest.approx(independent, rel=0.01) and c[0] != 0
    masses = [correction(cal, *nominal).mass_mg for cal in cals]  # g moves kz too: m = K2 H / kz / (2 b^2 sin 2 theta)
    assert c[1] == pytest.approx((masses[0] - masses[1]) / (2 * u_g), rel=0.01, abs=1e-3 * abs(independent * mass))
    # both calibrations see the same g: its row carries both, so they are correlated in the covariance
    assert c[2] != 0 and budget.covariance()[0, 2] != 0


def test_seed004_gum_json_carries_the_budget(seed004_case) -> None:
    from procedures.nonlinear_suppression.analysis import Suppression, SweepFit, correction, report_html
    from procedures.nonlinear_suppression.budget import suppression_budget

    s1, s2, best, after = seed004_case
    nominal = (0.1, 20.607, 45.0)
    budget = suppression_budget(s1.station, (s1.points, best), (s2.points, after), nominal, REFS, timer_rows=False)
    offsets, k2 = np.array([-1.0, 0.0, 1.0, 2.0]), np.array([3e-5, 1.1e-5, 2e-5, 4e-5])
    sweep = SweepFit(offsets, k2, k2 / 100, 0.0, 0.1, 1.1e-5, 1e-7, 0.0, 1.1e-5)
    s = Suppression([best, after], sweep, best, correction(best, *nominal), after, budget)
    doc = s.gum()
    assert_gum_json(doc, ("K2_at_best", "removed_mass", "K2_after_removal"))
    assert "Uncertainty budget of the headline figures" in report_html(s, "t")
    assert doc["coefficients"]["removed_mass"]["sigma"] == pytest.approx(s.correction.sigma_mass_mg)


@pytest.mark.slow
def test_seed004_monte_carlo_coverage() -> None:
    n = 30
    tally = mc.seed004(n, 14, REFS)
    lo, _ = coverage_band(n)
    cover = np.mean(tally.covered, axis=0)
    assert np.all(cover >= lo), dict(zip(tally.names, cover, strict=True))


# ---------------------------------------------------------------- through the procedures' own analyses


def test_procedure_analyses_of_seeds_001_and_004_write_the_budget_in_their_results() -> None:
    """What station.cli.analysis_job prints: the procedure's analyse(session) results, JSON-safe, with the GUM
    fields."""
    import json

    from procedures.nonlinear_suppression.analysis import AFTER_REMOVAL, AT_BEST, SWEEP, servo_offset_measurement
    from procedures.nonlinear_suppression.procedure import analyse_suppression, sweep_prefix
    from procedures.tumble.procedure import analyse as analyse_tumble_session
    from procedures.tumble.tumble_session import tumble_session
    from station.jsonsafe import json_safe
    from station.twin.config import default_twin
    from station.twin.pendulous_accelerometer import CF_NAMES, AccelerometerModel
    from station.twin.plan import multiposition_plan
    from station.twin.session_sim import simulate_session

    session, _ = tumble_session(AccelerometerModel(), [20.0, 80.0], 3, 8e-6, np.random.default_rng(2))
    doc = json.loads(json.dumps(json_safe(analyse_tumble_session(session).results)))
    for t in doc["eight_point"]["temperatures"]:
        assert_gum_json({"coefficients": t["coefficients"], **t["gum_cf"]}, CF_NAMES)

    plan = multiposition_plan([0.0, 180.0, 60.0], [8.0, 9.0, 10.0], 560.0)
    groups = [(sweep_prefix(i), SWEEP, x) for i, x in enumerate([-1.0, 0.0, 1.0, 2.0])]
    groups += [("B", AT_BEST, 0.0), ("A", AFTER_REMOVAL, 0.0)]
    points, measurements = [], []
    for j, (prefix, stage, offset) in enumerate(groups):
        s = simulate_session(plan, default_twin(), seed=100 + j)
        measurements.append(servo_offset_measurement(f"offset-{j}", prefix, stage, offset))
        points += [replace(p, point_id=f"{prefix}-{p.point_id}") for p in s.points]
    analysis = analyse_suppression(Session(s.station, points, measurements=measurements))
    doc = json.loads(json.dumps(json_safe(analysis.results)))["suppression"]["gum"]
    assert_gum_json(doc, ("K2_at_best", "removed_mass", "K2_after_removal"))
    assert "Uncertainty budget of the headline figures" in analysis.report_html


# ---------------------------------------------------------------- the generic machinery


def test_transformed_and_stacked_budgets_follow_the_chain_rule_and_keep_shared_inputs_correlated() -> None:
    """y = (a, b) from a fit (Type A cov C, dof 8) and one input x (u = 2, c = (1, 3)); z = a / b by the chain rule
    J = (1/b, -a/b^2): Cov(z) = J (C + c c^T u^2) J^T (GUM eq. 13). Two such budgets on independent data that
    share x: the fits block-diagonal, x's row side by side, so Cov(z1, z2) = (J1 c) (J2 c) u^2."""
    from procedures.common.uncertainty import Input, fit_budget, refit_sources, stacked, transformed

    cov = np.array([[0.5, 0.1], [0.1, 0.2]])
    y = np.array([2.0, 4.0])
    rows = refit_sources([Input("x", "input x", 0.0, 2.0, "V")], lambda x: y + np.array([1.0, 3.0]) * x["x"])
    b = fit_budget(("a", "b"), y, cov, 8, {"a": "V", "b": "V"}, rows)
    np.testing.assert_allclose(b.covariance(), cov + 4.0 * np.outer([1.0, 3.0], [1.0, 3.0]))
    J = np.array([[1 / y[1], -y[0] / y[1] ** 2]])
    z = transformed(b, ("z",), np.array([y[0] / y[1]]), J, {"z": "1"})
    expected = (J @ (cov + 4.0 * np.outer([1.0, 3.0], [1.0, 3.0])) @ J.T).item()
    assert z.covariance()[0, 0] == pytest.approx(expected)
    # Welch-Satterthwaite: u_A^4 / 8 is the only finite-dof term
    u_a2, u_b2 = (J @ cov @ J.T).item(), ((J @ [1.0, 3.0]) ** 2 * 4.0).item()
    assert z.effective_dof()[0] == pytest.approx((u_a2 + u_b2) ** 2 / (u_a2**2 / 8))
    z2 = transformed(b, ("w",), np.array([y[0] / y[1]]), J, {"w": "1"})
    both = stacked(z, z2)
    cross = ((J @ [1.0, 3.0]) ** 2 * 4.0).item()
    np.testing.assert_allclose(both.covariance(), [[expected, cross], [cross, expected]])
