"""Cost of the station clocks (station/clock.py, station/event_clock.py): CPU per timer event and per hand-off.

    .venv/bin/python bench/bench_clock.py

(a) EventClock: N call_every ticks run by one sleeping thread (no parties): CPU per timer event.
(b) EventClock: two parties handing a token back and forth through a condition, one station
    millisecond apart: CPU and wall per hand-off (a thread switch each).
(c) WallClock: the same hand-off through the wall clock's condition (no station time), for scale.

Simulation path: none (the clocks alone, no station, no session).
"""

from __future__ import annotations

import argparse
import threading
import time

from station.clock import Clock, WallClock
from station.event_clock import EventClock


def timer_events(n: int) -> tuple[float, float]:
    clock = EventClock()
    count = [0]
    clock.call_every(0.001, lambda: count.__setitem__(0, count[0] + 1))
    c0, w0 = time.process_time(), time.perf_counter()
    clock.sleep_s((n + 0.5) * 0.001)  # half a period over: float sums of the grid land either side of n ms
    assert count[0] == n
    return (time.process_time() - c0) / n, (time.perf_counter() - w0) / n


def hand_offs(clock: Clock, n: int, step_s: float) -> tuple[float, float]:
    cond = clock.condition()
    turn = [0]

    def player(me: int) -> None:
        for _ in range(n):
            with cond:
                cond.wait_for(lambda: turn[0] % 2 == me)
                turn[0] += 1
                cond.notify_all()
            if step_s:
                clock.sleep_s(step_s)

    both = threading.Barrier(2)  # both parties registered before either waits: time may not move without one

    def run(me: int) -> None:
        if isinstance(clock, EventClock):
            with clock.party(f"player {me}"):
                both.wait()
                player(me)
        else:
            player(me)

    threads = [threading.Thread(target=run, args=(me,)) for me in (0, 1)]
    c0, w0 = time.process_time(), time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return (time.process_time() - c0) / (2 * n), (time.perf_counter() - w0) / (2 * n)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--events", type=int, default=200_000)
    ap.add_argument("--hand-offs", type=int, default=20_000)
    args = ap.parse_args()
    cpu, wall = timer_events(args.events)
    print(f"(a) EventClock timer event: {cpu * 1e6:.2f} us CPU, {wall * 1e6:.2f} us wall ({args.events} events)")
    cpu, wall = hand_offs(EventClock(), args.hand_offs, 0.001)
    print(f"(b) EventClock hand-off between two parties: {cpu * 1e6:.1f} us CPU, {wall * 1e6:.1f} us wall")
    cpu, wall = hand_offs(WallClock(), args.hand_offs, 0.0)
    print(f"(c) WallClock hand-off between two threads: {cpu * 1e6:.1f} us CPU, {wall * 1e6:.1f} us wall")


if __name__ == "__main__":
    main()
