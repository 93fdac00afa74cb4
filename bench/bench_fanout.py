"""Fan-out speed: gap-validation cases per second on one process, 2 local processes and a 2-worker dask
LocalCluster (issue 16), and whether the verdicts agree.

The cases are `station gap-validate --design seed000 --snr 10 --reps R`'s, over the effects of EFFECTS and
NULLS null sessions (each: a 40-point session simulated and diagnosed blind). Cluster start-up is timed
apart from the cases. Machine: 2 cores shared with other work, so the load average is printed too.

    .venv/bin/python bench/bench_fanout.py [--reps R] [--scheduler ADDRESS]

Simulation path: the session_sim shortcut (not the engine): station.gap.validate's cases simulate their sessions with
station.twin.session_sim.
"""

from __future__ import annotations

import argparse
import os
import time

from station.fanout import ExecutorSpec, open_executor, run_cases
from station.gap.validate import cases, run_case

EFFECTS = ("cross_coupling", "odd_quadratic", "bias_drift", "frequency_error")
NULLS = 4


def timeless(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "elapsed_s"} for r in rows]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--reps", type=int, default=2)
    p.add_argument("--scheduler", help="also time an existing dask cluster")
    args = p.parse_args()
    todo = cases(["seed000"], [10.0], args.reps, NULLS, 1, EFFECTS, ("quartic_term",))
    specs = [
        ("1 process (inline)", ExecutorSpec("local", workers=1)),
        ("local pool, 2 processes", ExecutorSpec("local", workers=2)),
        ("dask LocalCluster, 2 workers", ExecutorSpec("dask", workers=2)),
    ]
    if args.scheduler:
        specs.append((f"dask scheduler {args.scheduler}", ExecutorSpec("dask", scheduler=args.scheduler)))
    print(f"{len(todo)} cases; load average before: {os.getloadavg()[0]:.2f}\n")
    print("| executor | start-up s | cases s | cases/s | verdicts as on 1 process |")
    print("|---|---|---|---|---|")
    reference = None
    for name, spec in specs:
        t = time.perf_counter()
        with open_executor(spec) as ex:  # start-up alone: a trivial task
            ex.submit(abs, -1).result()
        startup_s = time.perf_counter() - t
        t = time.perf_counter()
        rows = run_cases(run_case, todo, spec)
        wall_s = time.perf_counter() - t
        reference = reference or timeless(rows)
        same = "yes" if timeless(rows) == reference else "NO"
        print(f"| {name} | {startup_s:.1f} | {wall_s:.1f} | {len(todo) / wall_s:.2f} | {same} |", flush=True)
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
