"""Seed 002's figures on the simulated station: Table 1's coefficients, the velocity-error decreases of
Table 2, and the speed of the IMU recordings.

session: `rlg_g_sensitivity` with config/procedures/rlg_g_sensitivity.toml (the seed's
    15-minute alignments, 10-minute vibrations at 1.5 g, 20 Hz in the nine poses, and its two
    verification runs) through the engine, the drivers and the emulators; the estimates against the
    simulated IMU's true coefficients (seed 002 Table 1), wall and station time.
table2: the 27 verification runs of Table 2 (sine 1 g 10 Hz x3, 1.5 g 10 Hz x6, 0.5 g 20 Hz x6, 1 g 20 Hz
    x6, 2 g 20 Hz x3, random 0.7 g RMS 10-60 Hz x3, along the SINS's diagonal, 15-minute alignment,
    10-minute vibration) made off line from the twin (procedures.rlg_g_sensitivity.vibration_run), compensated with the
    estimate of an off-line calibration of the same lengths: the percentage decrease of each. Run i has its
    own generator (seed [SEED, i]), so the 27 runs fan out with the same figures on every executor
    (station/fanout.py).

    .venv/bin/python bench/bench_seed002.py [session|table2|all] [--seed N] [--executor local|dask]
        [--scheduler ADDRESS] [--workers W] [--results CASES.jsonl]

Simulation paths: session through the engine on the deterministic station; table2 a shortcut (not the engine):
procedures.rlg_g_sensitivity.vibration_run, the IMU's increments straight from the twin, for the compensation's figures.
The two do not agree run by run (other mount errors and sensor draws; the engine's windows a batch longer);
tests/test_simulation_paths_seed002.py checks that the shortcut's calibration runs are statistically the engine's
on a common design (the nine poses, 20-s alignments and vibrations: the runs' design equal, A within the mount
error, B - A tau and the twelve coefficients against the twin's truth and each other).
"""

from __future__ import annotations

import argparse
import functools
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers.config import load_station_config
from drivers.station import simulated_station
from procedures.rlg_g_sensitivity.analysis import RunRecord, estimate_flexure, navigate, observe_run
from procedures.rlg_g_sensitivity.procedure import VELOCITY_BLOCK_S
from procedures.rlg_g_sensitivity.vibration_run import SimulatedRun, simulate_run
from station.cli.controller import StationController
from station.constants import EARTH_RATE_RADPS, G_MPS2, LATITUDE_DEG
from station.engine.registry import load_procedure_file
from station.fanout import ExecutorSpec, add_executor_options, run_cases, spec_from_args
from station.store import SessionStore
from station.twin.config import default_twin
from station.twin.fixture_poses import CALIBRATION_POSES, POSES
from station.twin.shaker_motion import random_drive, sine_drive
from station.twin.strapdown_imu import ARCSEC_PER_G, TABLE1_ARCSEC_PER_G, TAU_NAMES, Site, StrapdownImuTwin

ROOT = Path(__file__).resolve().parents[1]
SITE = Site(G_MPS2, EARTH_RATE_RADPS, math.radians(LATITUDE_DEG))
TABLE2 = [("1 g, 10 Hz", 1.0, 10.0, 3), ("1.5 g, 10 Hz", 1.5, 10.0, 6), ("0.5 g, 20 Hz", 0.5, 20.0, 6),
          ("1 g, 20 Hz", 1.0, 20.0, 6), ("2 g, 20 Hz", 2.0, 20.0, 3), ("random", 0.7, 0.0, 3)]  # fmt: skip
ALIGN_S, VIBRATE_S, RATE_HZ = 900.0, 600.0, 200.0


def record(run: SimulatedRun) -> RunRecord:
    return RunRecord.from_times(run.dtheta, run.dv, run.dt_s, 0.0, run.t0_s, run.tk_s)


def table1(values: np.ndarray, sigmas: np.ndarray) -> None:
    print("| coefficient | estimate (arcsec/g) | σ | seed Table 1 (the twin's truth) | error / σ |")
    print("|---|---|---|---|---|")
    for name, v, s, t in zip(TAU_NAMES, values, sigmas, TABLE1_ARCSEC_PER_G, strict=True):
        print(f"| τ_{name} | {v:+.4f} | {s:.4f} | {t:+.3f} | {(v - t) / s:+.2f} |")


def session(seed: int) -> None:
    config = load_station_config(ROOT / "config" / "stations/shaker-sim.toml")
    spec, params = load_procedure_file(ROOT / "config" / "procedures" / "rlg_g_sensitivity.toml")
    with (
        tempfile.TemporaryDirectory() as tmp,
        simulated_station(config, default_twin(), seed=seed, speed=1000.0) as sim,
        SessionStore(Path(tmp) / "station.sqlite") as store,
    ):
        controller = StationController(sim.devices, store, config.station_model(), reports_dir=tmp)
        wall = time.perf_counter()
        outcome = controller.run(spec.name, params)
        wall = time.perf_counter() - wall
        station_s = controller.engine.progress.elapsed_s
    assert outcome.analysis is not None, outcome.faults
    r = outcome.analysis.results["flexure"]
    print(f"session: {outcome.state}, {station_s / 3600:.2f} h of station time in {wall:.0f} s of wall time "
          f"({station_s / wall:.1f}x); residual σ {r['sigma_residual_arcsec']:.3f} arcsec, {r['dof']} dof, "
          f"condition {r['condition']:.2f}\n")  # fmt: skip
    table1(np.array(r["values_arcsec_per_g"]), np.array(r["sigmas_arcsec_per_g"]))
    print()
    for c in outcome.analysis.results["verification"]["runs"]:
        print(f"{c['key']}: |δv| {c['v_end_uncompensated_mps']:.4f} -> {c['v_end_compensated_mps']:.4f} m/s "
              f"after {c['vibration_s']:.0f} s: -{c['decrease_pct']:.1f} %")  # fmt: skip


def offline_calibration(twin: StrapdownImuTwin, rng: np.random.Generator) -> np.ndarray:
    a, b = [], []
    for k in CALIBRATION_POSES:
        run = simulate_run(twin, SITE, POSES[k], sine_drive(20.0, 1.5, G_MPS2), rate_hz=RATE_HZ, align_s=ALIGN_S,
                           vibrate_s=VIBRATE_S, ramp_s=2.0, rng=rng)  # fmt: skip
        obs = observe_run(record(run), SITE)
        a.append(obs.A)
        b.append(obs.B)
    fit = estimate_flexure(np.vstack(a), np.concatenate(b))
    print("off-line calibration (the seed's run lengths):\n")
    table1(fit.values / ARCSEC_PER_G, fit.sigmas / ARCSEC_PER_G)
    return fit.values


def table2_run(case: tuple[int, float, float], seed: int, tau_hat: list[float]) -> float:
    """Decrease of the velocity error (%) of verification run `case` = (i, level g, frequency Hz; 0: random)."""
    i, level, freq = case
    twin, rng = StrapdownImuTwin(), np.random.default_rng([seed, i])
    drive = random_drive(level, 10.0, 60.0, G_MPS2, rng) if freq == 0 else sine_drive(freq, level, G_MPS2)
    run = simulate_run(twin, SITE, POSES[10], drive, rate_hz=RATE_HZ, align_s=ALIGN_S, vibrate_s=VIBRATE_S,
                       ramp_s=2.0, rng=rng)  # fmt: skip
    return navigate(record(run), SITE, np.asarray(tau_hat), round(VELOCITY_BLOCK_S * RATE_HZ)).decrease


def table2(seed: int, spec: ExecutorSpec | None = None, results: str | None = None) -> None:
    twin, rng = StrapdownImuTwin(), np.random.default_rng(seed)
    wall = time.perf_counter()
    tau_hat = offline_calibration(twin, rng)
    print("\n| vibration | decrease of the velocity error, % (27 runs along the SINS's diagonal) |")
    print("|---|---|")
    labels = [label for label, _, _, count in TABLE2 for _ in range(count)]
    runs = [(i, level, freq) for i, (level, freq) in enumerate((lv, f) for _, lv, f, n in TABLE2 for _ in range(n))]
    one = functools.partial(table2_run, seed=seed, tau_hat=[float(x) for x in tau_hat])
    spec = spec or ExecutorSpec("local", workers=1)
    decreases = run_cases(one, runs, spec, results=results, settings={"bench": "seed002.table2", "seed": seed})
    for label, *_ in TABLE2:
        row = [d for name, d in zip(labels, decreases, strict=True) if name == label]
        print(f"| {label} | {', '.join(f'{d:.1f}' for d in row)} |")
    d = np.array(decreases)
    print(f"\nabove 30 %: {np.mean(d > 30) * 100:.0f} % of the runs (seed: about 82 %); median {np.median(d):.1f} %; "
          f"{time.perf_counter() - wall:.0f} s")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("part", nargs="?", default="all", choices=("session", "table2", "all"))
    parser.add_argument("--seed", type=int, default=2)
    add_executor_options(parser)
    args = parser.parse_args()
    if args.part in ("session", "all"):
        session(args.seed)
    if args.part in ("table2", "all"):
        table2(args.seed, spec_from_args(args), args.results)


if __name__ == "__main__":
    main()
