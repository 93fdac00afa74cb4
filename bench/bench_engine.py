"""The main job's speed: seed 000's full session through engine, drivers and emulators on the simulated station.

    .venv/bin/python bench/bench_engine.py [--speeds 500 1000] [--repeats 1]

Runs config/procedures/integral_precession.toml (10 positions, 8/9/10 Hz and static, 40 points) on the
deterministic simulated station of config/stations/vibration-sim.toml (discrete-event clock, the real drivers against
their emulators) as fast as the CPU allows and, for each of `--speeds`, paced at that ceiling (station
seconds per wall second, as `--speed` for watching live), and prints a markdown table: wall time, CPU,
station time, station seconds per wall second, peak RSS of the process, and the identified kzz and k3
against the twin's truth in units of their sigma (the same seed gives the same values at any pace).

Simulation path: through the engine on the deterministic station.
"""

from __future__ import annotations

import argparse
import platform
import resource
import tempfile
import time
from pathlib import Path

from drivers.config import load_station_config
from drivers.station import simulated_station
from station.cli.controller import StationController
from station.engine.registry import load_procedure_file
from station.store import SessionStore
from station.twin.config import default_twin

ROOT = Path(__file__).resolve().parents[1]


def run_once(speed: float | None, seed: int) -> dict:
    cfg = load_station_config(ROOT / "config" / "stations/vibration-sim.toml")
    spec, params = load_procedure_file(ROOT / "config" / "procedures" / "integral_precession.toml")
    twin = default_twin()
    with tempfile.TemporaryDirectory() as tmp:
        t0, cpu0 = time.perf_counter(), time.process_time()
        with simulated_station(cfg, twin, seed=seed, speed=speed) as sim, SessionStore(Path(tmp) / "s.sqlite") as st:
            controller = StationController(sim.devices, st, cfg.station_model(), reports_dir=tmp)
            outcome = controller.run(spec.name, params)
            station_s = controller.engine.progress.elapsed_s
        wall_s, cpu_s = time.perf_counter() - t0, time.process_time() - cpu0
    k = twin.instrument
    coef = outcome.analysis.results["integral"]["coefficients"] if outcome.analysis else {}
    z = {n: (coef[n]["value"] - getattr(k, n)) / coef[n]["sigma"] for n in ("kzz", "k3")} if coef else {}
    return {"state": str(outcome.state), "wall_s": wall_s, "cpu_s": cpu_s, "station_s": station_s, "z": z}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speeds", type=float, nargs="*", default=[], help="ceilings to run beside the unpaced run")
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    print(f"machine: {platform.machine()}, {platform.python_implementation()} {platform.python_version()}")
    print("\n| pace | outcome | wall (s) | CPU (s) | station (h) | station-s per wall-s | (kzz - true)/σ "
          "| (k3 - true)/σ |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for speed in [None, *args.speeds]:
        for r in range(args.repeats):
            res = run_once(speed, seed=r)
            z = res["z"]
            pace = "as fast as the CPU allows" if speed is None else f"at most {speed:g}x"
            print(f"| {pace} | {res['state']} | {res['wall_s']:.1f} | {res['cpu_s']:.1f} | "
                  f"{res['station_s'] / 3600:.2f} | "
                  f"{res['station_s'] / res['wall_s']:.0f} | {z.get('kzz', float('nan')):+.2f} | "
                  f"{z.get('k3', float('nan')):+.2f} |", flush=True)  # fmt: skip
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\npeak RSS of the process over all runs: {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
