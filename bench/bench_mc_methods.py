"""Monte Carlo of the GUM budgets of seeds 001-004: is U (95 %) a 95 % interval? (issue 15, deliverable 7)

For each method, N sessions from its fast twin path with every Type B input of its budget drawn from the
distribution the references file states (config/instruments/references.toml: rectangular where it says
rectangular, else normal), the session then identified and budgeted exactly as the results JSON does it; per
headline coefficient the mean and spread of (k_hat - k) / u_c and the fraction of sessions with
|k_hat - k| <= U = k u_c (k from Student's t at the Welch-Satterthwaite dof; target 0.93-0.97).

- 001: procedures.tumble.tumble_session (4 temperatures x 3 cycles, 8 ug a reading), eq. 6 at T1; drawn: the
  index head's angle error at each of the 8 head angles, the voltmeter's gain and offset.
- 002: procedures.rlg_g_sensitivity.vibration_run, the 9 calibration poses at 20 Hz, 1.5 g, runs of `--align-s` at
rest and
  `--vibrate-s` of vibration (shorter than the seed's, for time); drawn: each accelerometer's scale factor, each
  gyro's residual bias, the IMU's sampling interval, the latitude (the twin's site is off the recorded one).
- 003: both PIGAs' static rates (drivers.second_instrument.emulator.static_rates_radps: the fixture's physics)
  in the four-pose design (22 equal-acceleration positions in setup 1, 22 equal-angle in setup 2) and A's
  22-position equal-angle calibration, 2e-7 rad/s per window; drawn: the head's six angle-error harmonics, the
  head zero (the self-alignment's error, 8e-6 rad), the latitude. Headline: A's coefficients without
  (`uncompensated`) and with (`compensated_total`) the compensation.
- 003-indep: the same budget without compensation on static rates from tests/indep's world (physics.md
  implemented again, sharing no code with the twin): per session a random design (equal-angle or
  equal-acceleration, 12-36 positions), an instrument of indep.generator.random_coefficients with a koq of
  either sign (fitted with physics.md's static model, k3 included), white rate noise 5e-8 to 1e-6 rad/s, and
  drawn as stated the head's harmonics k = 1..3, the head zero's error (8e-6 rad) and the latitude. Three
  tallies: the budget as it was (eq. 48's sigma as Type A, k from t alone), with the Type A at the rate noise
  alone but k from t, and as it is (Type A at the noise, k for the stated shapes).
- 004: station.twin.session_sim of the calibration at the best offset and the one after the removal (0, 180, 60 deg
  at 8, 9, 10 Hz, 5 dof each, noise pooled over the two: 10 dof); drawn: seed 000's inputs
  (bench_mc_seed000.drawn_twin) and H, b, theta of eqs. 21-22. Headline: K2 at the best offset and after, and
  the removed mass.

    .venv/bin/python bench/bench_mc_methods.py --method 001|002|003|003-indep|004|all [--n 200] [--seed 1]

Simulation paths: shortcuts (not the engine), for the budgets' honesty: 001 procedures.tumble.tumble_session, 002
procedures.rlg_g_sensitivity.vibration_run, 003 the fixture's static rates (and tests/indep's world for 003-indep),
004 the
session_sim shortcut (not the engine): station.twin.session_sim.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from procedures.common.references import Reference, load_references
from procedures.common.uncertainty import Budget


def draw(rng: np.random.Generator, ref: Reference, size: int | None = None) -> np.ndarray | float:
    """An input's error from its stated distribution: rectangular of half-width sqrt(3) u, else normal."""
    u = ref.standard_uncertainty
    if ref.shape == "rectangular":
        return rng.uniform(-math.sqrt(3.0) * u, math.sqrt(3.0) * u, size)
    return rng.normal(0.0, u, size)


def all_normal(refs: dict[str, Reference]) -> dict[str, Reference]:
    """--normal: every reference normal with its u, drawn and budgeted so (tests the propagation, not the shape)."""
    return {k: replace(r, distribution=f"normal (--normal; stated: {r.distribution})") for k, r in refs.items()}


@dataclass
class Tally:
    """Per coefficient: (k_hat - k) / u_c, coverage of U, and nu_eff, over the sessions."""

    names: tuple[str, ...]
    z: list[np.ndarray]
    covered: list[np.ndarray]
    dof: list[np.ndarray]

    def add(self, budget: Budget, truth: np.ndarray) -> None:
        err = budget.values - truth
        self.z.append(err / budget.standard_uncertainty())
        self.covered.append(np.abs(err) <= budget.expanded_uncertainty())
        self.dof.append(budget.effective_dof())

    def print(self, label: str, wall_s: float) -> None:
        z, cover, dof = map(np.array, (self.z, self.covered, self.dof))
        n = z.shape[0]
        print(f"\n{label}: {n} sessions in {wall_s:.0f} s\n")
        print("| coefficient | mean z | spread z | nu_eff (median) | coverage of U (95 %) |")
        print("|---|---:|---:|---:|---:|")
        for j, name in enumerate(self.names):
            nu = np.median(dof[:, j])
            nu_text = "inf" if math.isinf(nu) else f"{nu:.1f}"
            print(
                f"| {name} | {z[:, j].mean():+.3f} | {z[:, j].std(ddof=1):.3f} | {nu_text} | {cover[:, j].mean():.3f} |"
            )
        print(f"(binomial 95 % half-width at 0.95 over {n}: {1.96 * math.sqrt(0.0475 / n):.3f})")


def seed001(n: int, seed: int, refs: dict[str, Reference]) -> Tally:
    from procedures.tumble.analysis import analyse_tumble
    from procedures.tumble.tumble_session import tumble_session
    from station.twin.pendulous_accelerometer import CF_NAMES, AccelerometerModel

    m, rng = AccelerometerModel(), np.random.default_rng(seed)
    tally = Tally(CF_NAMES, [], [], [])
    for _ in range(n):
        session, truths = tumble_session(
            m, [20.0, 80.0, -40.0, 20.0], 3, sigma_g=8e-6, rng=rng,
            head_error_rad=draw(rng, refs["tumble_head_angle_rad"], 8),
            voltmeter_gain=draw(rng, refs["voltmeter_gain"]), voltmeter_offset_v=draw(rng, refs["voltmeter_offset_v"]),
        )  # fmt: skip
        _, points, _ = analyse_tumble(session, m.reference_c, refs)
        tally.add(points[0].budget, np.array([truths[0][c] for c in CF_NAMES]))
    return tally


def seed002(n: int, seed: int, refs: dict[str, Reference], align_s: float = 120.0, vibrate_s: float = 60.0) -> Tally:
    from procedures.rlg_g_sensitivity.analysis import RunRecord, observation_values, observe_run
    from procedures.rlg_g_sensitivity.budget import flexure_budget
    from procedures.rlg_g_sensitivity.vibration_run import simulate_run
    from station.constants import EARTH_RATE_RADPS, G_MPS2, LATITUDE_DEG
    from station.twin.fixture_poses import CALIBRATION_POSES, POSES
    from station.twin.shaker_motion import sine_drive
    from station.twin.strapdown_imu import ARCSEC_PER_G, TAU_NAMES, Site, StrapdownImuTwin

    recorded = Site(G_MPS2, EARTH_RATE_RADPS, math.radians(LATITUDE_DEG))
    twin, rng = StrapdownImuTwin(), np.random.default_rng(seed)
    truth = np.array(twin.tau) / ARCSEC_PER_G
    tally = Tally(tuple(f"tau_{t}" for t in TAU_NAMES), [], [], [])
    rate_hz = 200.0
    for _ in range(n):
        accel = np.array([draw(rng, refs["imu_accel_scale"]) for _ in range(3)])
        clock = float(draw(rng, refs["imu_clock_rel"]))
        imu = replace(twin, gyro_bias_radps=tuple(draw(rng, refs["imu_gyro_bias_radps"]) for _ in range(3)))
        site = replace(recorded, latitude_rad=recorded.latitude_rad + math.radians(draw(rng, refs["latitude_deg"])))
        runs = []
        for k in CALIBRATION_POSES:
            run = simulate_run(imu, site, POSES[k], sine_drive(20.0, 1.5, G_MPS2), rate_hz=rate_hz / (1.0 + clock),
                               align_s=align_s, vibrate_s=vibrate_s, ramp_s=2.0, rng=rng)  # fmt: skip
            record = RunRecord.from_times(run.dtheta, run.dv * (1.0 + accel), 1.0 / rate_hz, 0.0, run.t0_s, run.tk_s)
            runs.append(observation_values(observe_run(record, recorded)) | {"align_s": record.i0 * record.dt_s})
        tally.add(flexure_budget(runs, recorded, refs), truth)
    return tally


def four_pose_windows(twin, rng: np.random.Generator | None, noise_radps: float) -> list:
    """Both PIGAs' windows of seed 003's four-pose design (22 equal-acceleration positions of A in setup 1, 22
    equal-angle in setup 2), from the fixture's physics, with white rate noise (none without `rng`)."""
    from drivers.second_instrument.emulator import static_rates_radps
    from procedures.multiposition.four_pose import PoseWindow
    from procedures.multiposition.sequences import sequence_deg
    from station.twin.fixture import POSES_DEG, SETUPS

    windows = []
    for setup in (1, 2):
        positions = sequence_deg("equal_acceleration" if setup == 1 else "equal_angle", 22)
        heads = np.radians((np.array(positions) - POSES_DEG[SETUPS[setup][0]]) % 360)
        for inst, (pose, rates) in static_rates_radps(twin, setup, heads).items():
            noisy = rates if rng is None else rates + rng.normal(0.0, noise_radps, rates.size)
            windows += [PoseWindow(inst, setup, pose, h, r) for h, r in zip(heads, noisy, strict=True)]
    return windows


ZERO_SIGMA_RAD = 8e-6  # the self-alignment's sigma at seed 003's figures (eq. 56: about 1.8 arcsec)


def seed003(n: int, seed: int, refs: dict[str, Reference]) -> tuple[Tally, Tally]:
    from drivers.second_instrument.emulator import static_rates_radps
    from procedures.multiposition import budget as gum
    from procedures.multiposition.four_pose import fit_four_pose, harmonic_names
    from procedures.multiposition.sequences import sequence_deg
    from procedures.multiposition.static_model import MODELS, fit_static, true_static_terms, with_angle_uncertainty
    from station.session import StationInfo
    from station.twin.config import TwinConfig
    from station.twin.fixture import pose_rad

    base = TwinConfig.from_toml(Path(__file__).parents[1] / "config" / "twins" / "multiposition.toml")
    station, terms, rng = StationInfo(), MODELS["seed003"], np.random.default_rng(seed)
    noise = 2e-7
    cal_rad = np.radians(sequence_deg("equal_angle", 22))
    tm = np.full(cal_rad.size, 600.0)
    tallies = Tally(terms, [], [], []), Tally(terms, [], [], [])
    for _ in range(n):
        harmonics = {h: float(draw(rng, refs["index_harmonic_rad"])) for h in harmonic_names(3)}
        lat = station.latitude_deg + float(draw(rng, refs["latitude_deg"]))
        zero_err = rng.normal(0.0, ZERO_SIGMA_RAD)  # A's input axis off the head zero the analysis takes as exact
        twin = base.with_effect("index_harmonics", **harmonics).with_effect("mount_misalignment", dtheta_mount=zero_err)
        twin = replace(twin, station=replace(base.station, latitude_deg=lat))
        windows = four_pose_windows(twin, rng, noise)
        rates = static_rates_radps(twin, 1, cal_rad)["A"][1] + rng.normal(0.0, noise, cal_rad.size)
        aligned = cal_rad + pose_rad(1)
        unc = fit_static(aligned, rates, terms, station)
        truth_terms = true_static_terms(twin.instrument, twin.param("odd_quadratic", "koq"))
        truth = np.array([truth_terms[t] for t in terms])
        tallies[0].add(gum.uncompensated_budget(unc, cal_rad, aligned, rates, tm, station, 3, ZERO_SIGMA_RAD, refs),
                       truth)  # fmt: skip
        fp = fit_four_pose(windows, terms, 3, station)
        angles = fp.instrument_angle_rad("A", 1, 1, cal_rad)
        comp = fit_static(angles, rates, terms, station)
        total = with_angle_uncertainty(comp, angles, fp.angle_derivatives(cal_rad), fp.angle_covariance("A", 1),
                                       station)  # fmt: skip
        tallies[1].add(gum.compensated_budget(comp, total, fp, windows, 1, 1, cal_rad, rates, tm, station, refs),
                       truth)  # fmt: skip
    return tallies


def t_only(budget: Budget) -> Budget:
    """The budget with every input taken normal: k from Student's t alone (the coverage rule before the shapes)."""
    return replace(budget, sources=[replace(s, shape="normal") for s in budget.sources])


def seed003_indep(n: int, seed: int, refs: dict[str, Reference]) -> tuple[Tally, Tally, Tally]:
    sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
    from indep.generator import random_coefficients
    from indep.world import Perturbation, StationConsts, Window

    from procedures.common.uncertainty import with_fit
    from procedures.multiposition import budget as gum
    from procedures.multiposition.four_pose import harmonic_names
    from procedures.multiposition.sequences import SCHEMES, sequence_deg
    from procedures.multiposition.static_model import MODELS, fit_static
    from station.session import StationInfo

    station, terms, rng = StationInfo(), MODELS["physics"], np.random.default_rng(seed)
    tallies = tuple(Tally(terms, [], [], []) for _ in range(3))
    for _ in range(n):
        co = replace(random_coefficients(rng), koq=float(rng.uniform(-2e-5, 2e-5)))
        h = np.array([draw(rng, refs["index_harmonic_rad"]) for _ in harmonic_names(3)])
        pe = Perturbation(
            idx_c_rad=(*h[0::2], 0.0), idx_s_rad=(*h[1::2], 0.0), mount_rad=rng.normal(0.0, ZERO_SIGMA_RAD)
        )
        consts = StationConsts(latitude_deg=station.latitude_deg + float(draw(rng, refs["latitude_deg"])))
        head_deg = np.array(sequence_deg(SCHEMES[rng.integers(len(SCHEMES))], int(rng.integers(12, 37))))
        noise = math.exp(rng.uniform(math.log(5e-8), math.log(1e-6)))
        rates = np.array([Window(co, pe, th, 0.0, 0.0, 0.0, st=consts).r_static for th in head_deg])
        rates += rng.normal(0.0, noise, rates.size)
        head = np.radians(head_deg)
        fit = fit_static(head, rates, terms, station)
        now = gum.uncompensated_budget(fit, head, head, rates, np.full(head.size, 600.0), station, 3, ZERO_SIGMA_RAD,
                                       refs)  # fmt: skip
        truth = np.array([co.k0 + co.ky, co.kz, co.kzz - co.ky, co.koq, co.k3])
        tallies[0].add(t_only(with_fit(now, fit.cov, fit.dof, "eq. 48's sigma")), truth)
        tallies[1].add(t_only(now), truth)
        tallies[2].add(now, truth)
    return tallies


def seed004(n: int, seed: int, refs: dict[str, Reference]) -> Tally:
    from bench_mc_seed000 import drawn_twin

    from procedures.nonlinear_suppression.analysis import AFTER_REMOVAL, AT_BEST, calibrate, correction, pooled
    from procedures.nonlinear_suppression.budget import suppression_budget
    from station.twin import nonlinear_error as ne
    from station.twin.plan import multiposition_plan
    from station.twin.session_sim import simulate_session

    plan = multiposition_plan([0.0, 180.0, 60.0], [8.0, 9.0, 10.0], 560.0)
    rng = np.random.default_rng(seed)
    nominal = (ne.ANGULAR_MOMENTUM_KGM2PS, ne.END_RADIUS_M * 1e3, 45.0)
    tally = Tally(("K2_at_best", "removed_mass", "K2_after_removal"), [], [], [])
    for i in range(n):
        cfg, recorded = drawn_twin(rng, refs, 1.0)
        k = cfg.instrument
        s1 = replace(simulate_session(plan, cfg, seed=seed * 100_000 + 2 * i), station=recorded)
        s2 = replace(simulate_session(plan, cfg, seed=seed * 100_000 + 2 * i + 1), station=recorded)
        best, after = pooled([calibrate(recorded, s1.points, "B", AT_BEST, 0.0),
                              calibrate(recorded, s2.points, "A", AFTER_REMOVAL, 0.0)])  # fmt: skip
        true_h = nominal[0] + draw(rng, refs["angular_momentum_kgm2ps"])
        true_b = nominal[1] + draw(rng, refs["end_radius_mm"])
        true_theta = nominal[2] + draw(rng, refs["removal_angle_deg"])
        true_cal = replace(best, kz=k.kz, kzz=k.kzz)
        true_mass = correction(true_cal, true_h, true_b, true_theta).mass_mg
        budget = suppression_budget(recorded, (s1.points, best), (s2.points, after), nominal, refs, timer_rows=False)
        tally.add(budget, np.array([k.kzz / k.kz, true_mass, k.kzz / k.kz]))
    return tally


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", choices=("001", "002", "003", "003-indep", "004", "all"), default="all")
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--normal", action="store_true", help="every Type B input normal, drawn and budgeted")
    args = ap.parse_args()
    refs = all_normal(load_references()) if args.normal else load_references()
    runs: dict[str, tuple[str, Callable]] = {
        "001": ("seed 001, eq. 6 at T1 (dof 43)", seed001),
        "002": ("seed 002, flexure coefficients (9 calibration runs, dof 6)", seed002),
        "003": ("seed 003, A's coefficients", seed003),
        "003-indep": ("seed 003 without compensation, static rates from tests/indep", seed003_indep),
        "004": ("seed 004, K2 and removed mass (pooled dof 10)", seed004),
    }
    for key, (label, run) in runs.items():
        if args.method not in (key, "all"):
            continue
        t0 = time.perf_counter()
        out = run(args.n, args.seed, refs)
        wall = time.perf_counter() - t0
        if key == "003-indep":
            for tally, how in zip(
                out,
                (
                    "as it was (eq. 48's sigma, k from t)",
                    "Type A at the rate noise, k from t",
                    "as it is (Type A at the noise, k for the stated shapes)",
                ),
                strict=True,
            ):
                tally.print(f"{label}: {how}", wall)
        elif isinstance(out, tuple):
            out[0].print(f"{label} without compensation", wall)
            out[1].print(f"{label} with compensation (compensated_total)", wall)
        else:
            out.print(label, wall)


if __name__ == "__main__":
    main()
