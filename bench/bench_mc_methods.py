"""Monte Carlo of the GUM expanded uncertainties of seeds 001, 002 and 004 (issue 15, deliverable 7).

For each method, N sessions from its fast twin path; per headline coefficient the mean and spread of
(k_hat - k) / u and the coverage of U = k u with k = t_95(dof) as the results JSON states it (target
0.93-0.97). Type A only for these methods (their JSON says which Type B inputs are not propagated);
the twins have none of those inputs, so the figures test the Type A part and its t factor.

- seed 001: methods.seed001.tumble_session (the seed's 4 temperatures x 3 cycles, 8 ug per reading),
  eq. 6 coefficients at T1 (the JSON's `gum_cf`).
- seed 002: methods.seed002.vibration_run, the 6 calibration poses at 20 Hz, 1.5 g (runs of 300 s here),
  the flexure coefficients (the JSON's flexure.gum).
- seed 004: models.session_sim of one seed-004 calibration (0, 180, 60 deg at 8, 9, 10 Hz, 5 dof) and
  K2 = kzz / kz with its own noise (no pooling: the hardest case for the t factor).

    .venv/bin/python bench/bench_mc_methods.py [--method 001|002|004|all] [--n 200]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from methods.common.uncertainty import coverage_factor
from methods.seed004.analysis import calibrate
from models.config import default_twin
from models.plan import multiposition_plan
from models.session_sim import simulate_session


def _table(label: str, names, z: np.ndarray, cover: np.ndarray, dof: float, wall: float, n: int) -> None:
    print(f"\n{label}: {n} sessions in {wall:.0f} s, dof {dof:g}, k = {coverage_factor(dof):.3f}\n")
    print("| coefficient | mean (k_hat - k)/u | spread | coverage of U (95 %) |")
    print("|---|---|---|---|")
    for j, name in enumerate(names):
        print(f"| {name} | {z[:, j].mean():+.3f} | {z[:, j].std(ddof=1):.3f} | {cover[:, j].mean():.3f} |")
    print(f"(binomial half-width at 0.95 over {n}: {1.96 * math.sqrt(0.0475 / n):.3f})")


def seed001(n: int) -> None:
    from methods.seed001.analysis import analyse_tumble
    from methods.seed001.tumble_session import tumble_session
    from models.pendulous_accelerometer import CF_NAMES, AccelerometerModel

    m, rng = AccelerometerModel(), np.random.default_rng(1)
    z, cover = [], []
    t0 = time.perf_counter()
    for _ in range(n):
        session, truths = tumble_session(m, [20.0, 80.0, -40.0, 20.0], 3, sigma_g=8e-6, rng=rng)
        _, points, _ = analyse_tumble(session, m.reference_c)
        doc = points[0].to_json()["coefficients"]
        err = np.array([doc[c]["value"] - truths[0][c] for c in CF_NAMES])
        u = np.array([doc[c]["standard_uncertainty"] for c in CF_NAMES])
        U = np.array([doc[c]["expanded_uncertainty"] for c in CF_NAMES])
        z.append(err / u)
        cover.append(np.abs(err) <= U)
        dof = points[0].dof
    _table("seed 001, eq. 6 at T1", CF_NAMES, np.array(z), np.array(cover), dof, time.perf_counter() - t0, n)


def seed002(n: int, vibrate_s: float = 300.0) -> None:
    from methods.common.uncertainty import type_a_json
    from methods.seed002.analysis import RunRecord, estimate_flexure, observe_run
    from methods.seed002.vibration_run import simulate_run
    from models.fixture_poses import CALIBRATION_POSES, POSES
    from models.shaker_motion import sine_drive
    from models.strapdown_imu import ARCSEC_PER_G, TAU_NAMES, Site, StrapdownImuTwin
    from station.constants import EARTH_RATE_RADPS, G_MPS2, LATITUDE_DEG

    site = Site(G_MPS2, EARTH_RATE_RADPS, math.radians(LATITUDE_DEG))
    twin, rng = StrapdownImuTwin(), np.random.default_rng(2)
    truth = np.array(twin.tau) / ARCSEC_PER_G
    z, cover = [], []
    t0 = time.perf_counter()
    for _ in range(n):
        a, b = [], []
        for k in CALIBRATION_POSES:
            run = simulate_run(twin, site, POSES[k], sine_drive(20.0, 1.5, G_MPS2), rate_hz=200.0, align_s=900.0,
                               vibrate_s=vibrate_s, ramp_s=2.0, rng=rng)  # fmt: skip
            obs = observe_run(RunRecord.from_times(run.dtheta, run.dv, run.dt_s, 0.0, run.t0_s, run.tk_s), site)
            a.append(obs.A)
            b.append(obs.B)
        fit = estimate_flexure(np.vstack(a), np.concatenate(b))
        coefs: dict[str, dict] = {}
        type_a_json(coefs, TAU_NAMES, fit.values / ARCSEC_PER_G, fit.cov / ARCSEC_PER_G**2, fit.dof,
                    dict.fromkeys(TAU_NAMES, "arcsec/g"), "")  # fmt: skip
        err = np.array([coefs[t]["value"] for t in TAU_NAMES]) - truth
        z.append(err / np.array([coefs[t]["standard_uncertainty"] for t in TAU_NAMES]))
        cover.append(np.abs(err) <= np.array([coefs[t]["expanded_uncertainty"] for t in TAU_NAMES]))
        dof = fit.dof
    _table("seed 002, flexure coefficients (Table 1)", [f"tau_{t}" for t in TAU_NAMES], np.array(z),
           np.array(cover), dof, time.perf_counter() - t0, n)  # fmt: skip


def seed004(n: int) -> None:
    cfg = default_twin()
    k = cfg.instrument
    truth = k.kzz / k.kz
    plan = multiposition_plan([0.0, 180.0, 60.0], [8.0, 9.0, 10.0], 560.0)
    z, cover = [], []
    t0 = time.perf_counter()
    for i in range(n):
        s = simulate_session(plan, cfg, seed=40_000 + i)
        cal = calibrate(s.station, s.points, "C", "sweep", 0.0)
        err = cal.k2_per_g - truth
        u = cal.sigma_k2_per_g
        z.append([err / u])
        cover.append([abs(err) <= coverage_factor(cal.dof) * u])
        dof = cal.dof
    _table("seed 004, K2 = kzz / kz of one calibration", ["K2"], np.array(z), np.array(cover), dof,
           time.perf_counter() - t0, n)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", choices=("001", "002", "004", "all"), default="all")
    ap.add_argument("--n", type=int, default=200)
    args = ap.parse_args()
    for name, run in (("001", seed001), ("002", seed002), ("004", seed004)):
        if args.method in (name, "all"):
            run(args.n)


if __name__ == "__main__":
    main()
