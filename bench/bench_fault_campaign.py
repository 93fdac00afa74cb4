"""The fault campaign's table: every emulator fault, during a window and between windows, through the real drivers,
emulators, engine, supervisor and store; time to the typed error, time to a safe state, outcome.

    .venv/bin/python bench/bench_fault_campaign.py

Runs the cases of tests/test_fault_campaign.py (the same code: `run_case`) and prints a markdown table for
BENCHMARKS.md. Times from the injection, in wall seconds and station seconds (what the test bounds).

Simulation path: through the engine on the deterministic station (the fault campaign's cases, emulator faults
injected).
"""

from __future__ import annotations

import os
import platform
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]  # the project first: tests/devices (a namespace) must not shadow devices
sys.path.append(str(ROOT / "tests"))

from test_fault_campaign import CASES, PHASES, run_case  # noqa: E402


def main() -> None:
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    print("| fault | injected | typed error (first reported) | error after, station s (wall s) | safe state after, "
          "station s (wall s) | outcome |")  # fmt: skip
    print("|---|---|---|---:|---:|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            for phase in PHASES:
                r = run_case(case, phase, Path(tmp))
                kind = r.fault.split(":")[0] if not r.fault.startswith("repeat") else r.fault.split(": ")[2]
                safe = "point repeated" if r.safe_s is None else f"{r.safe_station_s:.2f} ({r.safe_s:.3f})"
                where = "during a window" if phase == "window" else "between windows"
                print(
                    f"| {case.name} | {where} | {kind} | {r.detect_station_s:.2f} ({r.detect_s:.3f}) | {safe} | "
                    f"{r.state.split('/')[1]}, "
                    f"{r.points} points kept |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
