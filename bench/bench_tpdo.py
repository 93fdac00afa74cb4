"""What the drive's cyclic TPDOs cost the deterministic station: the servo driver and its emulator on a
discrete-event clock (station.event_clock) and the `station_sim` CAN interface, the crank at 8 Hz, nothing else
running; CPU per station second and per TPDO frame, and where it goes (cProfile, by own time).

    .venv/bin/python bench/bench_tpdo.py [--station-s 60] [--top 15]

Simulation path: the servo driver and its emulator on the deterministic station's clock and CAN interface, without
the engine (no session).
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import platform
import pstats
import time
import uuid
from pathlib import Path

from drivers.config import load_station_config
from drivers.servo.driver import ServoLimits, VibrationTableServo
from drivers.servo.emulator import ServoEmulator
from drivers.sim_can import INTERFACE, bind_clock
from station.event_clock import EventClock

CONFIG = load_station_config(Path(__file__).resolve().parents[1] / "config" / "stations/vibration-sim.toml")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--station-s", type=float, default=60.0, help="station seconds at speed, measured")
    ap.add_argument("--top", type=int, default=15, help="functions listed")
    ap.add_argument("--sort", default="tottime", help="pstats sort key (tottime, cumulative)")
    args = ap.parse_args()
    clock = EventClock()
    channel = f"bench-tpdo-{uuid.uuid4().hex[:8]}"
    bind_clock(channel, clock)
    cfg = dataclasses.replace(CONFIG.servo, interface=INTERFACE, channel=channel)
    frames = 0
    try:
        with clock.party("bench"):
            emu = ServoEmulator.from_config(cfg, clock)
            emu.start()
            servo = VibrationTableServo(cfg, ServoLimits.from_config(CONFIG), clock)
            try:
                servo.open()
                servo.enable()
                servo.set_frequency(8.0)
                timers_s = [t.event_timer / 1000 for t in servo.node.tpdo.values() if t.enabled and t.event_timer]
                frames = round(sum(args.station_s / t for t in timers_s))
                cpu_s = time.process_time()
                clock.sleep_s(args.station_s)
                cpu_s = time.process_time() - cpu_s
                profile = cProfile.Profile()
                profile.runcall(clock.sleep_s, args.station_s)
            finally:
                servo.close()
                emu.stop()
    finally:
        bind_clock(channel, None)
    print(f"{platform.node()} {platform.processor() or platform.machine()}, CPython {platform.python_version()}")
    print(f"TPDO event timers {timers_s} s: {frames} frames in {args.station_s:g} s of station time")
    print(f"CPU {cpu_s:.3f} s: {cpu_s / args.station_s * 1e3:.1f} ms per station second, "
          f"{cpu_s / frames * 1e6:.1f} us per TPDO frame (timers, heartbeats and all)")  # fmt: skip
    pstats.Stats(profile).sort_stats(args.sort).print_stats(args.top)


if __name__ == "__main__":
    main()
