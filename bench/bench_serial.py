"""Serial transport benchmark: the real drivers against their emulators over ptys.

    .venv/bin/python bench/bench_serial.py [--seconds 20] [--queries 1000]

1. Sustained 5 kHz grating streaming at real time (VirtualClock speed 1, table
   vibrating at 10 Hz): samples received and lost (sequence/time-stamp gaps in
   the driver, FIFO drops in the emulator), CPU seconds per 1000 samples of the
   driver's thread and of the whole process (driver + emulator + world).
2. Indexing-head command round trip (`get pos`, a query, and `move abs`
   followed by `stop`) at 115200 baud: median and p99.

Prints a markdown table.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from devices.grating.driver import GratingReadHead
from devices.grating.emulator import GratingEmulator
from devices.indexing_head.driver import IndexingHead
from devices.indexing_head.emulator import IndexingEmulator
from devices.world import SimStation
from station.clock import VirtualClock


def make_world(speed: float = 1.0, vibrate_hz: float = 10.0) -> SimStation:
    world = SimStation(clock=VirtualClock(speed))
    if vibrate_hz > 0:
        t = world.clock.now_s()
        world.crank.command_speed(2 * math.pi * vibrate_hz, 1e6, t)
    return world


def bench_grating(seconds: float) -> dict[str, float]:
    world = make_world(1.0, 10.0)
    with GratingEmulator(world) as emu, GratingReadHead(emu.port, clock=world.clock) as head:
        head.start_streaming()
        head.read_for(500)  # warm up
        n0, lost0 = head.stats.samples, head.stats.lost_samples
        seq_first: int | None = None
        seq_last = 0
        cpu_thread0, cpu_proc0, wall0 = time.thread_time(), time.process_time(), time.monotonic()
        while time.monotonic() - wall0 < seconds:
            b = head.read_block()
            if len(b):
                seq_first = int(b.seq[0]) if seq_first is None else seq_first
                seq_last = int(b.seq[-1])
        cpu_thread = time.thread_time() - cpu_thread0
        cpu_proc = time.process_time() - cpu_proc0
        wall = time.monotonic() - wall0
        n = head.stats.samples - n0
        head.stop_streaming()
        expected = seq_last - (seq_first or 0) + 1
        return {
            "wall_s": wall,
            "samples": n,
            "expected": expected,
            "lost": head.stats.lost_samples - lost0,
            "dropped": emu.dropped,
            "rate_hz": n / wall,
            "cpu_driver_per_1000": 1000 * cpu_thread / n,
            "cpu_process_per_1000": 1000 * cpu_proc / n,
        }


def bench_indexing(queries: int) -> dict[str, float]:
    world = make_world(1.0, 0.0)
    with IndexingEmulator(world) as emu, IndexingHead(emu.port, clock=world.clock) as head:
        head.position_deg()
        rt_query = []
        for _ in range(queries):
            t0 = time.perf_counter()
            head.position_deg()
            rt_query.append(time.perf_counter() - t0)
        rt_move = []
        for i in range(max(queries // 10, 10)):
            t0 = time.perf_counter()
            head.move_abs(1.0 + (i % 10))
            rt_move.append(time.perf_counter() - t0)
            head.stop()
    return {
        "query_median_ms": 1e3 * statistics.median(rt_query),
        "query_p99_ms": 1e3 * float(np.percentile(rt_query, 99)),
        "move_median_ms": 1e3 * statistics.median(rt_move),
        "move_p99_ms": 1e3 * float(np.percentile(rt_move, 99)),
        "n_query": len(rt_query),
        "n_move": len(rt_move),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="grating streaming time (wall)")
    ap.add_argument("--queries", type=int, default=1000, help="indexing-head queries")
    args = ap.parse_args()
    gr = bench_grating(args.seconds)
    ix = bench_indexing(args.queries)
    rows = [
        ("grating: streaming time (wall)", f"{gr['wall_s']:.1f} s"),
        ("grating: samples received / expected", f"{gr['samples']} / {gr['expected']}"),
        ("grating: lost (driver) / dropped (emulator FIFO)", f"{gr['lost']} / {gr['dropped']}"),
        ("grating: received rate", f"{gr['rate_hz']:.0f} Hz"),
        (
            "grating: driver thread CPU per 1000 samples",
            f"{gr['cpu_driver_per_1000'] * 1e3:.1f} ms",
        ),
        (
            "grating: process CPU per 1000 samples (driver + emulator + world)",
            f"{gr['cpu_process_per_1000'] * 1e3:.1f} ms",
        ),
        (
            f"indexing head: `get pos` round trip, median / p99 (n = {ix['n_query']})",
            f"{ix['query_median_ms']:.2f} / {ix['query_p99_ms']:.2f} ms",
        ),
        (
            f"indexing head: `move abs` round trip, median / p99 (n = {ix['n_move']})",
            f"{ix['move_median_ms']:.2f} / {ix['move_p99_ms']:.2f} ms",
        ),
    ]
    print("| measurement | value |")
    print("| --- | --- |")
    for name, value in rows:
        print(f"| {name} | {value} |")


if __name__ == "__main__":
    main()
