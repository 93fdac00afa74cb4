"""A short session on the wall-paced simulated station and on the deterministic one: station time, wall, CPU.

    .venv/bin/python bench/bench_deterministic.py [--repeats 2] [--raw] [--tpdo-ms MS] [--stations deterministic]

Runs seed 000's integral precession at 5 positions and 10 Hz with 30 s windows (each position with its
static point: 10 points) through the controller, engine, real drivers and emulators, on
`simulated_station(speed=1000)` (VirtualClock, ptys, python-can's virtual bus) and on
`simulated_station(deterministic=True)` (station.event_clock, sim:// lines, the station_sim CAN interface),
and prints a markdown table with the session's content hash (station.interchange.content_hash): the
deterministic rows must all carry one hash. `--tpdo-ms` overrides the station file's TPDO event timer (what
step 3 has to choose: the frames it costs).

Simulation path: through the engine on the deterministic station (and, for comparison, through the engine on the
wall-paced station).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import tempfile
import time
from pathlib import Path

from drivers.config import load_station_config
from drivers.station import simulated_station
from station.cli.controller import StationController
from station.interchange import content_hash
from station.store import SessionStore
from station.twin.config import default_twin

ROOT = Path(__file__).resolve().parents[1]
PROCEDURE = "integral_precession"
PARAMS = {"positions_deg": [0, 72, 144, 216, 288], "freqs_hz": [10], "window_s": 30, "settle_s": 2}


def run_once(deterministic: bool, raw: bool, tpdo_ms: int | None, seed: int = 1) -> dict:
    cfg = load_station_config(ROOT / "config" / "stations/vibration-sim.toml")
    if tpdo_ms is not None:
        cfg = dataclasses.replace(cfg, servo=dataclasses.replace(cfg.servo, tpdo_event_timer_ms=tpdo_ms))
    with tempfile.TemporaryDirectory() as tmp:
        wall0, cpu0 = time.perf_counter(), time.process_time()
        with (
            simulated_station(
                cfg, default_twin(), seed=seed, speed=None if deterministic else 1000.0, deterministic=deterministic
            ) as sim,
            SessionStore(Path(tmp) / "s.sqlite") as store,
        ):
            controller = StationController(sim.devices, store, cfg.station_model(), reports_dir=tmp)
            outcome = controller.run(PROCEDURE, PARAMS | {"raw": raw})
            station_s = controller.engine.progress.elapsed_s
            digest = content_hash(store.load_session(outcome.session_uid))[:12]
            controller.close()
        return {"state": str(outcome.state), "station_s": station_s, "wall_s": time.perf_counter() - wall0,
                "cpu_s": time.process_time() - cpu0, "hash": digest}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--raw", action="store_true", help="keep every pulse edge and grating stretch")
    ap.add_argument("--tpdo-ms", type=int, default=None, help="TPDO event timer (default: the station file's)")
    ap.add_argument("--stations", choices=("both", "deterministic"), default="both")
    args = ap.parse_args()
    print(f"machine: {platform.machine()}, {platform.python_implementation()} {platform.python_version()}")
    print("\n| station | outcome | station (s) | wall (s) | CPU (s) | content hash |")
    print("|---|---|---:|---:|---:|---|")
    for deterministic in (True,) if args.stations == "deterministic" else (False, True):
        for _ in range(args.repeats):
            r = run_once(deterministic, args.raw, args.tpdo_ms)
            name = "deterministic" if deterministic else "VirtualClock 1000x"
            print(f"| {name} | {r['state']} | {r['station_s']:.0f} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                  f"{r['hash']} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
