"""Seed 001's two simulation paths on a common design and common seeds: the engine on the deterministic tumble
station (config/stations/tumble-sim.toml) and the procedures.tumble.tumble_session shortcut (issue 27 step 3,
deliverable 4).

They cannot agree reading by reading: the shortcut draws the launch offset k0L and every reading's noise from one
generator in its own order, the station from the world's generators (the accelerometer's, the voltmeter's); the
shortcut's timeline is a fixed hour of soak and 20 s a reading where the station's follows the chamber's ramp and
settling and the head's moves, so the drift k0D t differs too. Measured on DESIGN, seed 1: the same plan of
readings (names, blocks, positions, strokes, where the head came from, to the bit), the readings (engine -
shortcut) / (K1 sigma_g) 2.8 rms: the two draws' sqrt(2), the launch offsets' difference (here 4.8 ug in k0
at T1, 0.6 sigma_g) and, before 2026-12-06's fix, one reading 36 sigma apart: the first. The voltmeter emulator's
accelerometer followed the head only when its line was used (on the discrete-event station an idle sim:// line is
not polled), so it never saw the move to -45 deg before the first reading and read it on no hysteresis branch,
h = 300 ug = 37 sigma_g off what the procedure means it to be; it now follows every head command
(test_the_engine_reads_the_first_tumble_reading_on_the_rising_branch). The agreement test checks what the
shortcut is kept for, the estimators' Monte Carlo: that its sessions are statistically the engine's. Measured
before the fix, without the first reading, on SEEDS: reading z sd 1.03 (engine) and 0.97 (shortcut) over 645
readings, the stroke fits' residual chi-square / dof 1.01 and 0.95 (513 dof), eq. 6's K0 .. Mip (estimate - truth) /
sigma at most 3.2
and 2.9 (rms 1.03, 1.00), eq. 4's at most 2.5 and 2.3, the paths' errors at most 2.9 sigma apart (rms 0.91).
It fails with the shortcut's reading noise 1.3x, its hysteresis 1.2x, or its k3 off by 10 ug/g^3.

Design: DESIGN over tumble.toml (the seed's 20, 80, -40, 20 C and three cycles: 216 readings; the chamber
at 5 C/min and a shorter soak to keep station time down), seeds SEEDS. Tolerances, each from the noise the twin
states: a reading is the mean of 10 conversions, each with the accelerometer's 16 ug/sqrt(Hz) over the 0.2 s
aperture (25.3 ug) and the voltmeter's 0.15 ppm of the 2 V range (0.07 ug): sigma_g = 8.0 ug a reading
(tests/engine_sessions.py tumble_reading_sigma_g; the shortcut is given the same). With z = (reading - truth) /
(K1 sigma_g), the truth eqs. 1 and 4 at the block's coefficients (the engine's: the accelerometer's model at the
mean product temperature of the block's readings, its own launch offset and drift):
- the two paths simulate the same instrument: each block's true K1 .. Mip within TRUTH_REL of each other, K0 / K1
  within 4.5 sqrt(2) of the launch offset's sigma plus an hour's drift;
- every reading's design fields (name, block, J, stroke, cycle, set point, position, the hysteresis branch of the
  head's path) identical; where the head came from within the head's settling tolerance (0.001 deg);
- per path, z pooled over seeds: |mean| <= 4 / sqrt(n), the variance within the chi-square(n - 1) bounds at
  two-sided 1e-4; engine against shortcut: variance ratio within F's bounds at two-sided 1e-3, means within
  4 sigma of each other;
- eq. 6 at each temperature (K0 .. Mip, the hysteresis h and the drift d of the stroke fit, 43 dof): per seed,
  block and path |estimate - truth| <= 4.5 sigma (Student t, 42-43 dof: p 5e-5 each, 192 of them); the two paths'
  errors (estimate - own truth: their launch offsets and times differ by design) within 4.5 sqrt(se^2 + ss^2);
  per path the mean over seeds and blocks of (estimate - truth) / sigma within 4 / sqrt(n);
- eq. 4 across temperatures (lambda_T1, lambda_T2, beta_T1, beta_T2, gamma_T1, gamma_T2, k0D; weighted by the
  blocks' sigmas, normal): per seed and path within 4.5 sigma of the truth, the paths' errors within
  4.5 sqrt(se^2 + ss^2);
- the stroke fits' residual sigma: per path sum(dof sigma^2 / (K1 sigma_g)^2) within the chi-square(sum dof)
  bounds at two-sided 1e-4, the paths' pooled variances in a ratio within F's bounds at two-sided 1e-3.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from engine_sessions import (
    assert_same_normal_scatter,
    chi2_ok,
    engine_tumble_session,
    f_ok,
    shortcut_tumble_session,
    tumble_params,
    tumble_reading_sigma_g,
)

from procedures.tumble.analysis import analyse_tumble, readings
from station.session import Session
from station.twin.pendulous_accelerometer import CF_NAMES, AccelerometerModel, tumble_inputs_g

DESIGN = {"ramp_c_per_min": 5.0, "soak_s": 1200.0}
SEEDS = range(1, 4)
# The true coefficients of a block: the engine's at the chamber's product temperature, within 0.02 C of the set
# point after the soak (beta_T 5.2e-4 / C: 1e-5 of K1), the shortcut's at the set point; k0 besides carries each
# path's launch offset (sigma 6.7 ug) and drift to its own times (k0D 4.6e-10 g/s; the timelines differ by less
# than an hour).
TRUTH_REL = 1e-5
BIAS_DRIFT_G = 2e-5 / 43200 * 3600
HEAD_TOL_DEG = 0.001  # config/stations/tumble-sim.toml [indexing_head] settle_tol_deg
LAWS = {  # eq. 4's laws: (TemperatureModel attribute, side) -> the model's field
    ("bias_g", "above"): "lambda_above_g_per_c",
    ("bias_g", "below"): "lambda_below_g_per_c",
    ("scale_factor", "above"): "beta_above_per_c",
    ("scale_factor", "below"): "beta_below_per_c",
    ("misalignment_rad", "above"): "gamma_above_rad_per_c",
    ("misalignment_rad", "below"): "gamma_below_rad_per_c",
    ("bias_g", "drift_per_s"): "drift_g_per_s",
}


def _design(s: Session) -> list[tuple]:
    r = readings(s)
    return [
        (m.key, m.values["block"], m.values["J"], m.values["stroke"], m.values["cycle"], m.values["setpoint_c"],
         m.values["position_deg"], b)
        for m, b in zip([m for m in s.measurements if m.kind == "tumble"], r.branch, strict=True)
    ]  # fmt: skip


def _from_deg(s: Session) -> np.ndarray:
    return np.array([m.values["from_deg"] for m in s.measurements if m.kind == "tumble"])


def _z_at_truth(s: Session, truths: list[dict[str, float]], m: AccelerometerModel, sigma_g: float) -> np.ndarray:
    """(reading - eqs. 1 and 4 at the block's true coefficients, drifting about its mean time) / (K1 sigma_g)."""
    r = readings(s)
    out = np.empty(r.volts.size)
    for block in r.blocks:
        keep = r.block == block
        k = truths[block]
        aI, aP, _ = tumble_inputs_g(np.radians((r.J[keep] - 1) * 45.0))
        t = r.t_s[keep] - r.t_s[keep].mean()
        clean = (k["K0"] + k["K1"] * (aI + m.drift_g_per_s * t - m.hysteresis_g * r.branch[keep])
                 + k["K2"] * aI**2 + k["K3"] * aI**3 + k["Mo"] * aP + k["Mip"] * aI * aP)  # fmt: skip
        out[keep] = (r.volts[keep] - clean) / (k["K1"] * sigma_g)
    return out


@pytest.mark.slow
def test_the_tumble_shortcut_is_statistically_the_engine_on_a_common_design() -> None:
    m = AccelerometerModel()
    p = tumble_params(DESIGN)
    sigma_g = tumble_reading_sigma_g(p, m)
    assert sigma_g == pytest.approx(8.0e-6, rel=1e-3)
    paths = ("engine", "shortcut")
    z = {path: [] for path in paths}
    coef_z = {path: [] for path in paths}  # per seed and block: (estimate - truth) / sigma of K0 .. Mip, h, d
    res = {path: [0.0, 0] for path in paths}  # sum dof sigma^2 / (K1 sigma_g)^2, sum dof
    for seed in SEEDS:
        runs = {"engine": engine_tumble_session(DESIGN, seed), "shortcut": shortcut_tumble_session(DESIGN, seed)}
        for block, (ke, ks) in enumerate(zip(runs["engine"][1], runs["shortcut"][1], strict=True)):
            for n in CF_NAMES[1:]:
                assert abs(ke[n] / ks[n] - 1) <= TRUTH_REL, f"seed {seed} T{block + 1}: true {n} {ke[n]} vs {ks[n]}"
            bias = abs(ke["K0"] / ke["K1"] - ks["K0"] / ks["K1"])
            assert bias <= 4.5 * math.sqrt(2) * m.launch_sigma_g + BIAS_DRIFT_G, f"seed {seed}: true k0 {bias} apart"
        se, ss = runs["engine"][0], runs["shortcut"][0]
        assert _design(se) == _design(ss), f"seed {seed}: the two paths measured different designs"
        head = np.abs(_from_deg(se) - _from_deg(ss)).max()
        assert head <= HEAD_TOL_DEG, f"seed {seed}: the head came from {head} deg elsewhere"
        errors = {}
        for path, (s, truths) in runs.items():
            z[path].append(_z_at_truth(s, truths, m, sigma_g))
            _, points, model = analyse_tumble(s, p["reference_c"])
            err = {}
            for point, k in zip(points, truths, strict=True):
                pairs = [(n, point.coefficient(n), k[n]) for n in CF_NAMES]
                pairs += [("h", point.hysteresis_g, m.hysteresis_g), ("d", point.drift_g_per_s, m.drift_g_per_s)]
                for n, (value, sigma), truth in pairs:
                    err[(point.block, n)] = (value - truth, sigma)
                coef_z[path].append([(v - t) / sd for _, (v, sd), t in pairs])
                res[path][0] += point.dof * (point.sigma_v / (k["K1"] * sigma_g)) ** 2
                res[path][1] += point.dof
            for (law, side), field in LAWS.items():
                value, sigma = getattr(getattr(model, law), side)
                truth = getattr(m, field)
                assert abs(value - truth) <= 4.5 * sigma, f"seed {seed} {path}: {field} {value} +- {sigma}, {truth}"
                err[(law, side)] = (value - truth, sigma)
            errors[path] = err
        for key, (de, sde) in errors["engine"].items():
            dc, sdc = errors["shortcut"][key]
            assert abs(de - dc) <= 4.5 * math.hypot(sde, sdc), (
                f"seed {seed}: {key} error engine {de} +- {sde}, shortcut {dc} +- {sdc}"
            )

    for path in paths:
        cz = np.array(coef_z[path])
        assert np.abs(cz).max() <= 4.5, f"{path}: (estimate - true) / sigma {cz.round(2).tolist()}"
        assert np.all(np.abs(cz.mean(axis=0)) <= 4 / math.sqrt(len(cz))), f"{path}: mean z {cz.mean(axis=0)}"
        sum_sq, dof = res[path]
        assert chi2_ok(sum_sq, dof, 1e-4), f"{path}: residual sigma^2 / expected pooled {sum_sq / dof:.3f} ({dof} dof)"
    assert_same_normal_scatter({path: np.concatenate(z[path]) for path in paths}, "readings")
    ratio = (res["engine"][0] / res["engine"][1]) / (res["shortcut"][0] / res["shortcut"][1])
    assert f_ok(ratio, res["engine"][1], res["shortcut"][1], 1e-3), f"residual variance ratio {ratio:.3f}"


def test_the_engine_reads_the_first_tumble_reading_on_the_rising_branch() -> None:
    """The procedure starts the head from -45 deg so that the first reading, at 0 deg, is on the rising branch
    (procedures.tumble.procedure); the analysis and the shortcut take it so. One temperature, one cycle, no soak."""
    m = AccelerometerModel()
    design = {"temperatures_c": [20.0], "cycles": 1, "soak_s": 0.0}
    session, truths = engine_tumble_session(design, 1)
    z = _z_at_truth(session, truths, m, tumble_reading_sigma_g(design, m))
    assert abs(z[0]) <= 4.5, f"first reading {z[0]:.1f} sigma off (the hysteresis is {m.hysteresis_g / 8e-6:.0f})"
