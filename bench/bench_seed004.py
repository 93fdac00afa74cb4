"""Seed 004's suppression of the quadratic term on the simulated station, against the seed's section 6 figures.

Runs config/procedures/nonlinear_suppression.toml (21 offsets, -5" .. 5" by 0.5", each calibrated by integral
precession; the best offset; eqs. 21-22; the operator's mass removal; K2 once more) on
config/stations/electronics-sim.toml for N station seeds at SPEED x real time (the CLI's 1000 by default; 500
keeps a loaded machine's late readers within half a time-stamp wrap), through the same CLI path an operator
uses, and prints each session's headline, the mean and spread over the sessions, and the wall time per session.
The sessions fan out (station/fanout.py): each in its own process with --workers 2 or on a dask cluster; on a
loaded machine, sessions side by side make each one's virtual clock late more often (see its faults).

    .venv/bin/python bench/bench_seed004.py [N] [SPEED] [--executor local|dask] [--scheduler ADDRESS]
        [--workers W] [--results CASES.jsonl]

Simulation path: through the engine on the deterministic station (`station run` of the procedure file in a child
process).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import tempfile
import time
from pathlib import Path

import numpy as np

from procedures.nonlinear_suppression.analysis import SEED_FIGURES
from station.cli.cli import main as station
from station.fanout import ExecutorSpec, add_executor_options, run_cases, spec_from_args
from station.store import SessionStore

CONFIG = Path(__file__).resolve().parents[1] / "config"
PROCEDURE = CONFIG / "procedures" / "nonlinear_suppression.toml"
STATION = CONFIG / "stations/electronics-sim.toml"


def run_session(seed: int, speed: float) -> tuple[dict | None, float, float]:
    """The headline of one simulated session (None if it did not finish), its station hours and wall seconds."""
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            args = ["--station", str(STATION), "--out", out, "--seed", str(seed), "--speed", str(speed)]
            code = station(["run", str(PROCEDURE), *args])
        wall_s = time.perf_counter() - t0
        with SessionStore(Path(out) / "station.sqlite") as store:
            (row,) = store.sessions()
            results = [r["result"] for r in store.results(row["uid"]) if r["method"] == "suppression"]
            station_h = store.load_session(row["uid"], with_raw=False).points[-1].start_s / 3600
    for line in printed.getvalue().splitlines():
        if "fault:" in line:
            print(f"seed {seed}: {line.strip()}")
    return (results[0]["headline"] if code == 0 else None), station_h, wall_s


def main(n: int, speed: float, spec: ExecutorSpec | None = None, results: str | None = None) -> None:
    rows = []
    one = functools.partial(run_session, speed=speed)
    spec = spec or ExecutorSpec("local", workers=1)
    runs = run_cases(one, list(range(n)), spec, results=results, settings={"bench": "seed004", "speed": speed})
    for seed, (headline, station_h, wall_s) in enumerate(runs):
        if headline is None:
            print(f"seed {seed}: did not finish, {station_h:.2f} h in {wall_s:.1f} s wall")
            continue
        rows.append(headline)
        print(f"seed {seed}: " + ", ".join(f"{k} {v:.4g}" for k, v in headline.items())
              + f"; {station_h:.2f} h of station time in {wall_s:.1f} s wall")  # fmt: skip
    if not rows:
        raise SystemExit("no session finished")
    print(f"\n| figure | seed 004 | mean of {len(rows)} sessions | sd |\n|---|---|---|---|")
    for key, seed_value in SEED_FIGURES.items():
        values = np.array([r[key] for r in rows])
        print(f"| {key} | {seed_value:.4g} | {values.mean():.4g} | {values.std(ddof=1) if len(rows) > 1 else 0:.2g} |")


if __name__ == "__main__":
    cli = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    cli.add_argument("n", nargs="?", type=int, default=5, help="sessions, seeds 0..N-1 (default 5)")
    cli.add_argument("speed", nargs="?", type=float, default=1000.0, help="virtual clock speed (default 1000)")
    add_executor_options(cli)
    args = cli.parse_args()
    if args.workers is None and args.executor == "local":
        args.workers = 1  # one session at a time unless asked: each runs a whole simulated station
    main(args.n, args.speed, spec_from_args(args), args.results)
