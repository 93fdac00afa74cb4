"""Serial transport benchmark: the real drivers against their emulators over ptys.

    .venv/bin/python bench/bench_serial.py [--seconds 20] [--queries 1000] [--status 2000]

1. Sustained 5 kHz grating streaming at real time (VirtualClock speed 1, table
   vibrating at 10 Hz): samples received and lost (sequence/time-stamp gaps in
   the driver, FIFO drops in the emulator), CPU seconds per 1000 samples of the
   driver's thread and of the whole process (driver + emulator + world).
2. Indexing-head command round trip (`get pos`, a query, and `move abs`
   followed by `stop`) at 115200 baud: median and p99.
3. Counter/timer STATUS round trip (a 17-byte reply at 921600 baud, 184 us of
   line time) over a pty served by the emulator's thread and over a sim://
   line (the emulator called in the driver's thread, the line paced in station
   time): process CPU and wall per round trip. The sim:// line runs on a
   VirtualClock at speed 1 (its line time is then wall time) and at speed 1000
   (line time nearly free, as on a discrete-event clock).

Prints a markdown table.

Simulation path: the serial drivers against their emulators, without the engine (no session).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from drivers.counter_timer.driver import CounterTimer
from drivers.counter_timer.emulator import CounterEmulator
from drivers.grating.driver import GratingReadHead
from drivers.grating.emulator import GratingEmulator
from drivers.indexing_head.driver import IndexingHead
from drivers.indexing_head.emulator import IndexingEmulator
from drivers.world import SimStation
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


def bench_status(transport: str, speed: float, queries: int) -> dict[str, float]:
    """CPU and wall per counter/timer STATUS round trip over `transport` ("pty" or "sim")."""
    world = make_world(speed, 0.0)
    emu = CounterEmulator(world)
    port = emu.start() if transport == "pty" else emu.start_sim()
    try:
        with CounterTimer(port, clock=world.clock) as board:
            for _ in range(50):  # warm up
                board.status()
            cpu0, wall0 = time.process_time(), time.perf_counter()
            for _ in range(queries):
                board.status()
            cpu_s, wall_s = time.process_time() - cpu0, time.perf_counter() - wall0
    finally:
        emu.close()
    return {"cpu_us": 1e6 * cpu_s / queries, "wall_us": 1e6 * wall_s / queries}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="grating streaming time (wall)")
    ap.add_argument("--queries", type=int, default=1000, help="indexing-head queries")
    ap.add_argument("--status", type=int, default=2000, help="counter/timer STATUS round trips per transport")
    args = ap.parse_args()
    gr = bench_grating(args.seconds)
    ix = bench_indexing(args.queries)
    status = {
        "pty (emulator thread), speed 1": bench_status("pty", 1.0, args.status),
        "sim:// (driver's thread), speed 1": bench_status("sim", 1.0, args.status),
        "sim:// (driver's thread), speed 1000": bench_status("sim", 1000.0, args.status),
    }
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
    rows += [
        (
            f"counter/timer STATUS round trip over {name}: CPU / wall (n = {args.status})",
            f"{st['cpu_us']:.0f} / {st['wall_us']:.0f} us",
        )
        for name, st in status.items()
    ]
    print("| measurement | value |")
    print("| --- | --- |")
    for name, value in rows:
        print(f"| {name} | {value} |")


if __name__ == "__main__":
    main()
