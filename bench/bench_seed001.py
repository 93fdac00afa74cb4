"""Seed 001 on the simulated tumble station: the seed's AL-15 figures reproduced, the estimators' honesty, speed.

(a) The seed's session (config/procedures/tumble.toml: 20, 80, -40 and back to 20 C, three cycles of
    forward and back strokes) through engine, drivers and emulators on config/stations/tumble-sim.toml at SPEED
    times real time (500: a loaded machine's pauses make the indexing head miss its 120 s settling at 1000x);
    the twin carries the seed's AL-15 estimates. Each figure the seed quotes, the estimate with its
    sigma, and z = (estimate - twin) / sigma (the twin's k0 also holds the launch offset k0L it drew).
(b) N sessions straight from the model (procedures.tumble.tumble_session): mean and spread of z per coefficient.
    Draw k has its own generator (seed [2, k]), so the figures are the same on every executor
    (station/fanout.py: --executor local|dask, --scheduler, --workers, --results CASES.jsonl to resume).

    .venv/bin/python bench/bench_seed001.py [N] [SPEED] [--executor local|dask] [--scheduler ADDRESS] [--workers W]
        [--results CASES.jsonl] [--no-session]

Simulation paths: (a) through the engine on the deterministic station; (b) a shortcut (not the engine):
procedures.tumble.tumble_session, the readings straight from the accelerometer model, for the estimators' honesty.
The two do not agree reading by reading (other draws, other timelines); tests/test_simulation_paths_seed001.py
checks that the shortcut's sessions are statistically the engine's on a common design (the plan of readings equal,
the readings' scatter, eq. 6 and eq. 4 against the twin's truth and each other), and pins the engine's first
reading, which the voltmeter's emulator reads on no hysteresis branch (an expected failure there).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers.config import load_station_config
from drivers.station import simulated_station
from drivers.voltmeter.emulator import accelerometer
from procedures.tumble.analysis import analyse_tumble
from procedures.tumble.tumble_session import tumble_session
from station.cli.controller import StationController
from station.engine.registry import load_procedure_file
from station.fanout import ExecutorSpec, add_executor_options, run_cases, spec_from_args
from station.store import SessionStore
from station.twin.config import default_twin
from station.twin.pendulous_accelerometer import CF_NAMES, AccelerometerModel

ROOT = Path(__file__).resolve().parents[1]
HALF_DAY_S = 43200.0


def station_session(seed: int, speed: float) -> None:
    config = load_station_config(ROOT / "config" / "stations/tumble-sim.toml")
    spec, params = load_procedure_file(ROOT / "config" / "procedures" / "tumble.toml")
    with tempfile.TemporaryDirectory() as tmp, SessionStore(Path(tmp) / "s.sqlite") as store:
        sim = simulated_station(config, default_twin(), seed=seed, speed=speed)
        try:
            controller = StationController(sim.devices, store, config.station_model(), reports_dir=tmp)
            wall0 = time.perf_counter()
            outcome = controller.run(spec.name, params)
            wall_s = time.perf_counter() - wall0
            station_s = controller.engine.progress.elapsed_s
            accel = accelerometer(sim.world)
        finally:
            sim.close()
        if outcome.faults:
            raise SystemExit(f"{outcome.state}: {outcome.faults}")
        _, points, model = analyse_tumble(store.load_session(outcome.session_uid), params["reference_c"])
    m, t1 = accel.model, points[0]
    k0_twin = m.k0_g + accel.bias_extra_g(t1.t_mean_s)
    rows = [  # (figure, unit, scale, seed 001, (estimate, sigma), twin value)
        ("k0 (bias at T0)", "mg", 1e3, "3.324", model.bias_g.at_reference, k0_twin),
        ("k2", "µg/g²", 1e6, "105", t1.coefficient("k2"), m.k2_g_per_g2),
        ("k3", "µg/g³", 1e6, "87", t1.coefficient("k3"), m.k3_g_per_g3),
        ("δo", "mrad", 1e3, "1.15", t1.coefficient("delta_o"), m.delta_o_rad),
        ("λT1", "µg/°C", 1e6, "-39", model.bias_g.above, m.lambda_above_g_per_c),
        ("λT2", "µg/°C", 1e6, "-45", model.bias_g.below, m.lambda_below_g_per_c),
        ("βT1", "ppm/°C", 1e6, "520", model.scale_factor.above, m.beta_above_per_c),
        ("βT2", "ppm/°C", 1e6, "480", model.scale_factor.below, m.beta_below_per_c),
        ("γT1 (not quoted by the seed)", "µrad/°C", 1e6, "—", model.misalignment_rad.above, m.gamma_above_rad_per_c),
        ("γT2 (not quoted by the seed)", "µrad/°C", 1e6, "—", model.misalignment_rad.below, m.gamma_below_rad_per_c),
        ("h_T (hysteresis)", "mg", 1e3, "±0.3 (3σ)", model.hysteresis_g, m.hysteresis_g),
        ("k0D over 12 h", "µg", HALF_DAY_S * 1e6, "≤ 20 (3σ)", model.bias_g.drift_per_s, m.drift_g_per_s),
    ]
    print(f"(a) {outcome.state}: {station_s / 3600:.2f} h of station time in {wall_s:.1f} s of wall time "
          f"({station_s / wall_s:.0f}x real time), {sum(p.n for p in points)} readings\n")  # fmt: skip
    print("| figure | unit | seed 001 | estimate ± σ | twin | z |")
    print("|---|---|---|---|---|---|")
    for name, unit, scale, seed_text, (value, sigma), twin in rows:
        print(f"| {name} | {unit} | {seed_text} | {value * scale:.4g} ± {sigma * scale:.2g} | {twin * scale:.4g} "
              f"| {(value - twin) / sigma:+.2f} |")  # fmt: skip
    k1 = ", ".join(f"{p.k1_3sigma_ppm:.1f}" for p in points)
    print(f"| k1 (SF instability, 3σ of K1) | ppm | 15 | {k1} (T1..T4) | | |")


def one_draw(k: int) -> dict[str, float]:
    """z = (estimate - truth) / sigma of every figure of draw k (its own generator, seed [2, k])."""
    m = AccelerometerModel()
    session, truths = tumble_session(m, [20.0, 80.0, -40.0, 20.0], 3, sigma_g=8e-6, rng=np.random.default_rng([2, k]))
    _, points, model = analyse_tumble(session, m.reference_c)
    z = {}
    for name in CF_NAMES:
        value, sigma = points[0].coefficient(name)
        z[f"{name} at T1"] = (value - truths[0][name]) / sigma
    h = points[0].hysteresis_g
    z["h at T1"] = (h[0] - m.hysteresis_g) / h[1]
    for name, pair, truth in (("λT1", model.bias_g.above, m.lambda_above_g_per_c),
                              ("λT2", model.bias_g.below, m.lambda_below_g_per_c),
                              ("βT1", model.scale_factor.above, m.beta_above_per_c),
                              ("βT2", model.scale_factor.below, m.beta_below_per_c),
                              ("k0D", model.bias_g.drift_per_s, m.drift_g_per_s)):  # fmt: skip
        z[name] = (pair[0] - truth) / pair[1]
    return z


def monte_carlo(n: int, spec: ExecutorSpec | None = None, results: str | None = None) -> None:
    wall0 = time.perf_counter()
    draws = run_cases(one_draw, list(range(n)), spec or ExecutorSpec(), results=results,
                      settings={"bench": "seed001", "rng": [2]})  # fmt: skip
    z = {name: [d[name] for d in draws] for name in draws[0]}
    print(f"\n(b) {n} sessions from the model (8 µg per reading) in {time.perf_counter() - wall0:.1f} s\n")
    print("| coefficient | mean z | std z |")
    print("|---|---|---|")
    for name, values in z.items():
        e = np.array(values)
        print(f"| {name} | {e.mean():+.3f} | {e.std(ddof=1):.3f} |")


if __name__ == "__main__":
    cli = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    cli.add_argument("n", nargs="?", type=int, default=500, help="Monte Carlo draws (default 500)")
    cli.add_argument("speed", nargs="?", type=float, default=500.0, help="station speed of (a) (default 500)")
    cli.add_argument("--no-session", action="store_true", help="only (b), the Monte Carlo")
    add_executor_options(cli)
    args = cli.parse_args()
    if not args.no_session:
        station_session(seed=1, speed=args.speed)
    monte_carlo(args.n, spec_from_args(args), args.results)
