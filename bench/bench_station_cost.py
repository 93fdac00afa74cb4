"""CPU per station second of the deterministic simulated station (config/stations/vibration-sim.toml): at rest and in a
counter window, the crank at 8 Hz; what the main job's 6.2 h are made of.

    .venv/bin/python bench/bench_station_cost.py [--station-s 600] [--repeats 3]

The calling thread is the clock's only party; CPU by time.process_time (the emulators and drivers all run in
it: timers fire in the waiting thread, CAN frames and sim:// bytes are delivered in the sender's). The least
of the repeats is printed (others' work on the host can only add to it).

Simulation path: the deterministic station's drivers and emulators without the engine (no session): the station's
cost per station second.
"""

from __future__ import annotations

import argparse
import cProfile
import platform
import pstats
import time
from pathlib import Path

from drivers.config import load_station_config
from drivers.station import simulated_station
from station.event_clock import EventClock
from station.twin.config import default_twin

CONFIG = Path(__file__).resolve().parents[1] / "config" / "stations/vibration-sim.toml"
FREQ_HZ = 8.0
PROBE_PULSES = 4000


def measure(station_s: float, profile: cProfile.Profile | None = None) -> tuple[float, float]:
    """(at rest, in a window) CPU seconds per station second."""
    with simulated_station(load_station_config(CONFIG), default_twin(), seed=0) as sim:
        clock = sim.world.clock
        assert isinstance(clock, EventClock)
        with clock.party("bench"):
            devices = sim.devices
            devices.set_vibration(FREQ_HZ)
            cpu_s = time.process_time()
            clock.sleep_s(station_s)
            rest = (time.process_time() - cpu_s) / station_s
            t0_s = clock.now_s()
            devices.measure_window(PROBE_PULSES)  # the pulse rate here, to size the window measured
            preset = round(PROBE_PULSES * station_s / (clock.now_s() - t0_s))
            t0_s, cpu_s = clock.now_s(), time.process_time()
            if profile is not None:
                profile.runcall(devices.measure_window, preset)
            else:
                devices.measure_window(preset)
            window = (time.process_time() - cpu_s) / (clock.now_s() - t0_s)
            devices.set_vibration(0.0)
    return rest, window


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--station-s", type=float, default=600.0, help="station seconds at rest and in the window")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--profile", type=int, default=0, help="then profile one window: print this many functions")
    args = ap.parse_args()
    runs = [measure(args.station_s) for _ in range(args.repeats)]
    rest, window = min(r[0] for r in runs), min(r[1] for r in runs)
    print(f"{platform.node()} {platform.machine()}, CPython {platform.python_version()}, {args.station_s:g} station s")
    print(f"at rest, crank at {FREQ_HZ:g} Hz: {rest * 1e3:.3f} ms of CPU per station second")
    print(f"in a counter window:        {window * 1e3:.3f} ms of CPU per station second")
    if args.profile:
        profile = cProfile.Profile()
        measure(args.station_s, profile)
        pstats.Stats(profile).sort_stats("tottime").print_stats(args.profile)


if __name__ == "__main__":
    main()
