"""Control channel under attack (issue 30, deliverables 5 and 7): the long fuzz campaign and the garbage floods.

One ControlServer over a controller that only records what it is asked (tests/control_fuzz.py), in this process;
garbage from other processes (tests/control_garbage.py), as another program on the machine would send it.

(a) fuzz: --examples hypothesis examples (seed --seed) of tests/test_fuzz_control.py: random, broken, replayed,
    stale and token-holder's odd frames, each followed by a valid request. Counted: what went wrong (lost valid
    request, unauthenticated action, ok reply to an unauthenticated frame, internal error, wrong reply count, dead
    thread), tracebacks in the server's log, peak RSS.
(b) burst: the issue's two experiments. 8 trials of one 64 kB random TCP burst, then a valid request (its
    latency); a burst every 0.5 s for --burst-s with a status request every 30 ms (lost: no reply in 2 s).
(c) flood: --flood-s of garbage from two processes while a client alternates estop and status every 20 ms
    (latency of each, lost, what the server refused, peak RSS); twice: every kind (raw TCP bursts, REQ-shaped
    frames with a wrong MAC, envelope-less multipart, a captured estop replayed), then the zmq kinds alone, which
    a process sends faster.

    .venv/bin/python bench/fuzz_control.py [--examples 20000] [--burst-s 30] [--flood-s 60] [--seed 30]

Simulation path: none (the control channel over a recording controller, no station, no session).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import resource
import socket
import statistics
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from control_fuzz import TOKEN, UNAUTHENTICATED, WRONG, Rig
from control_garbage import KINDS, flooding
from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st

from station.control_channel import ControlClient


class Tracebacks(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.n = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.n += record.exc_info is not None


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def ms(xs: list[float]) -> str:
    if not xs:
        return "none"
    q = statistics.quantiles(xs, n=100, method="inclusive") if len(xs) > 1 else [xs[0]] * 99
    return f"median {statistics.median(xs):.2f} ms, p99 {q[98]:.2f} ms, max {max(xs):.2f} ms (n {len(xs)})"


def fuzz(rig: Rig, examples: int, seed_: int) -> None:
    @seed(seed_)
    @settings(max_examples=examples, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))  # fmt: skip
    @given(data=st.data())
    def one(data: st.DataObject) -> None:
        rig.fuzz_one(data.draw)

    t0 = time.perf_counter()
    one()
    wall = time.perf_counter() - t0
    sent = sum(rig.counts[k] for k in ("unauthenticated", "stale", "authentic"))
    kinds = {k: rig.counts[k] for k in ("unauthenticated", *UNAUTHENTICATED, "stale", "authentic")}
    wrong = {k: rig.counts[k] for k in WRONG}
    print(f"(a) fuzz: {sent} messages in {wall:.1f} s {kinds}; gone wrong {wrong}; "
          f"server refusals {dict(rig.server.refusals.counts)}")  # fmt: skip


def request_ms(client: ControlClient, cmd: str) -> float | None:
    t0 = time.perf_counter()
    ok = client.request(cmd).get("ok")
    return (time.perf_counter() - t0) * 1000 if ok else None


def tcp_burst(endpoint: str) -> None:
    host, port = endpoint.removeprefix("tcp://").rsplit(":", 1)
    with socket.create_connection((host, int(port))) as s:
        s.sendall(os.urandom(65536))


def bursts(rig: Rig, burst_s: float) -> None:
    client = ControlClient(rig.server.endpoint, token=TOKEN, timeout_s=2.0)
    single = []
    for _ in range(8):
        tcp_burst(rig.server.endpoint)
        single.append(request_ms(client, "status"))
    answered = [x for x in single if x is not None]
    print(f"(b) one 64 kB burst, then a request: {len(answered)}/8 answered, {ms(answered)}")
    lat: list[float] = []
    lost = n = 0
    t0 = next_burst = time.perf_counter()
    while time.perf_counter() - t0 < burst_s:
        if time.perf_counter() >= next_burst:
            tcp_burst(rig.server.endpoint)
            next_burst += 0.5
        n += 1
        x = request_ms(client, "status")
        lost += x is None
        if x is not None:
            lat.append(x)
        time.sleep(0.03)
    client.close()
    print(f"(b) a burst every 0.5 s for {burst_s:g} s: {n} requests, {lost} lost; {ms(lat)}")


def flood(rig: Rig, flood_s: float, kinds: tuple[str, ...]) -> None:
    client = ControlClient(rig.server.endpoint, token=TOKEN, timeout_s=2.0)
    before = Counter(rig.server.refusals.counts)
    lat: dict[str, list[float]] = {"estop": [], "status": []}
    lost: Counter[str] = Counter()
    captured = rig.probe.signed(json.dumps({"cmd": "estop"}).encode())
    with flooding(rig.server.endpoint, kinds, replay=captured, processes=2):
        time.sleep(1.0)
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < flood_s:
            for cmd in ("estop", "status"):
                x = request_ms(client, cmd)
                if x is None:
                    lost[cmd] += 1
                else:
                    lat[cmd].append(x)
                time.sleep(0.02)
    client.close()
    refused = Counter(rig.server.refusals.counts)
    refused.subtract(before)
    per_s = {k: round(v / flood_s) for k, v in refused.items() if v}
    for cmd, xs in lat.items():
        print(f"(c) flood {'+'.join(kinds)} {flood_s:g} s, {cmd}: {ms(xs)}, lost {lost[cmd]}")
    print(f"(c) refused per second meanwhile: {per_s}; peak RSS {rss_mb():.0f} MB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=20000)
    ap.add_argument("--burst-s", type=float, default=30.0)
    ap.add_argument("--flood-s", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=30)
    args = ap.parse_args()
    print(f"{platform.node()}: {os.cpu_count()} cores, Python {platform.python_version()}")
    tracebacks = Tracebacks()
    logging.getLogger("station.cli.control").addHandler(tracebacks)
    logging.getLogger("station.cli.control").propagate = False  # the refusal lines would flood the terminal
    rig = Rig.start()
    try:
        fuzz(rig, args.examples, args.seed)
        print(f"    tracebacks in the server's log {tracebacks.n}, peak RSS {rss_mb():.0f} MB")
        bursts(rig, args.burst_s)
        flood(rig, args.flood_s, KINDS)
        flood(rig, args.flood_s, ("envelope", "bare", "replay"))
        print(f"tracebacks in the server's log {tracebacks.n}, peak RSS {rss_mb():.0f} MB, "
              f"controller calls {dict(Counter(rig.controller.calls))}")  # fmt: skip
    finally:
        rig.close()


if __name__ == "__main__":
    main()
