"""Every procedure file's full session on its simulated station, as a user runs it: station time, wall time, CPU.

    .venv/bin/python bench/bench_procedures.py [--only NAME ...] [--main-job]

Each config/procedures file runs through `station run FILE --station S` in a child process (start-up, the
session on the discrete-event station, the analysis child and the report included); its station is the one
tests/procedure_runs.py names for it. Station time is the plan's (the dry run's). CPU is the children's user +
system time (the analysis child included). Then (alone with --main-job) the main job against the shortcut (issue 27 d5):
`station calibrate` beside `station simulate` + `station identify` of the same design, in the same run.
Prints the Markdown tables of BENCHMARKS.md.

Simulation path: through the engine on the deterministic station for every procedure file and the main job; `station
simulate` in the comparison is the session_sim shortcut (not the engine): station.twin.session_sim, timed only.
"""

from __future__ import annotations

import argparse
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from procedure_runs import RUNS  # noqa: E402  (the station of every procedure file: one declaration)

STATION = [sys.executable, "-m", "station.cli.cli"]


def timed(args: list[str], cwd: Path) -> tuple[int, float, float, str]:
    """(exit code, wall s, CPU s of the child and its children, stdout) of `station ARGS`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall0 = time.perf_counter()
    proc = subprocess.run([*STATION, *args], cwd=cwd, capture_output=True, text=True, check=False)
    wall_s = time.perf_counter() - wall0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return proc.returncode, wall_s, cpu_s, proc.stdout + proc.stderr


def station_h(procedure: Path, station: Path, cwd: Path) -> float:
    _, _, _, out = timed(["run", str(procedure), "--station", str(station), "--dry-run"], cwd)
    found = re.search(r"([\d.]+) h of station time", out)
    return float(found.group(1)) if found else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", help="procedure file names (default: all)")
    ap.add_argument("--main-job", action="store_true", help="only the main job against the shortcut")
    args = ap.parse_args()
    names = [] if args.main_job else args.only or sorted(RUNS)
    print("| procedure file | station | station time (h) | exit | wall (s) | CPU (s) | station-s per wall-s |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name in names:
        station = ROOT / "config" / f"{RUNS[name][0]}.toml"
        procedure = ROOT / "config" / "procedures" / f"{name}.toml"
        with tempfile.TemporaryDirectory() as tmp:
            hours = station_h(procedure, station, Path(tmp))
            code, wall_s, cpu_s, _ = timed(
                ["run", str(procedure), "--station", str(station), "--out", tmp, "--yes"], Path(tmp)
            )  # --yes: seed 003's 99 h plan warns
        pace = hours * 3600 / wall_s if wall_s > 0 else float("nan")
        print(f"| {name} | {station.stem} | {hours:.2f} | {code} | {wall_s:.1f} | {cpu_s:.1f} | {pace:.0f} |",
              flush=True)  # fmt: skip
    if args.only:
        return
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)
        main_job = timed(["calibrate", "--out", "out"], cwd)
        simulate = timed(["simulate", "sim"], cwd)
        identify = timed(["identify", "sim", "--json", "ident.json"], cwd)
    shortcut_wall_s = simulate[1] + identify[1]
    print("\n| path | exit | wall (s) | CPU (s) |\n|---|---:|---:|---:|")
    print(f"| station calibrate (the main job) | {main_job[0]} | {main_job[1]:.1f} | {main_job[2]:.1f} |")
    print(f"| station simulate + station identify | {simulate[0]}, {identify[0]} | {shortcut_wall_s:.1f} | "
          f"{simulate[2] + identify[2]:.1f} |")  # fmt: skip
    print(f"\nmain job / shortcut, wall: {main_job[1] / shortcut_wall_s:.1f}x")


if __name__ == "__main__":
    main()
