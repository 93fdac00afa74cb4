"""Seed 004's suppression of the quadratic term on the simulated station, against the seed's section 6 figures.

Runs config/procedures/seed004_suppression.toml (21 offsets, -5" .. 5" by 0.5", each calibrated by integral
precession; the best offset; eqs. 21-22; the operator's mass removal; K2 once more) on
config/station-electronics-sim.toml for N station seeds at SPEED x real time (the CLI's 1000 by default; 500
keeps a loaded machine's late readers within half a time-stamp wrap), through the same CLI path an operator
uses, and prints each session's headline, the mean and spread over the sessions, and the wall time per session.

    .venv/bin/python bench/bench_seed004.py [N] [SPEED]
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from app.cli import main as station
from methods.seed004.analysis import SEED_FIGURES
from station.store import SessionStore

CONFIG = Path(__file__).resolve().parents[1] / "config"
PROCEDURE = CONFIG / "procedures" / "seed004_suppression.toml"
STATION = CONFIG / "station-electronics-sim.toml"


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


def main(n: int, speed: float) -> None:
    rows = []
    for seed in range(n):
        headline, station_h, wall_s = run_session(seed, speed)
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
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5, float(sys.argv[2]) if len(sys.argv) > 2 else 1000.0)
