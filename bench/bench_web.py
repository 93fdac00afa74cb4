"""Web panel: station-to-browser telemetry latency and throughput with 10 browsers, and the panel's memory.

Every figure is end to end: a station process publishes (pyzmq PUB), `station
panel` (its own process, as an operator starts it) relays over WebSocket, and
10 browsers (WebSocket clients in this process) receive. Latency is each
message's receive time minus its `wall_s` (stamped by the station when it
published); samples are the displacement-trace samples (z_m) a browser gets.

(a) station: a real `station serve` (simulated, 1000 x real time) runs the full
    40-point seed-000 session, started through the panel's API;
(b) stress: a synthetic station publishes trace messages of 250 samples at
    rising rates (plus the 5/s status beacon) for 10 s each;
(c) memory: one long session (the 40-point seed-000 session at --memory-speed,
    50 x real time by default: about 9 minutes) with 10 browsers, one of which
    never reads; the panel's RSS is sampled every 2 s.

    .venv/bin/python bench/bench_web.py [--clients 10] [--stress-rates 50 100 200 300 400] [--memory-speed 50]

Simulation path: through the engine on the deterministic station (a `station serve` child process).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx2
import numpy as np
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from web.auth import CSRF_HEADER, SESSION_COOKIE
from web.users import UserBook

PASSWORD = "bench-password"
TRACE_SAMPLES = 250
STRESS_S = 10.0
RSS_EVERY_S = 2.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def station_cli(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "station.cli.cli", *args], **kw)


def stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(40)
    except subprocess.TimeoutExpired:
        proc.kill()


@dataclass
class Panel:
    url: str
    pid: int
    headers: dict  # an operator's cookie and CSRF token

    def post(self, path: str, body: dict | None = None) -> dict:
        reply = httpx2.post(self.url + path, json=body, headers=self.headers, timeout=30)
        reply.raise_for_status()
        return reply.json()

    def status(self) -> dict:
        return httpx2.get(self.url + "/api/stations/sim/status", headers=self.headers, timeout=30).json()

    def cpu_s(self) -> float:
        """User plus system CPU time of the panel process."""
        fields = Path(f"/proc/{self.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def rss_mb(self) -> float:
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        raise RuntimeError("no VmRSS")


@contextlib.contextmanager
def panel_for(telemetry: str, control: str, home: Path) -> Iterator[Panel]:
    """`station panel` in front of one station, with an operator logged in."""
    UserBook(home / "users.json").add("bench", "operator", PASSWORD)
    port = free_port()
    config = home / "panel.toml"
    config.write_text(
        f'[panel]\nport = {port}\nusers = "{home}/users.json"\naudit_log = "{home}/audit.jsonl"\n\n'
        f'[[stations]]\nname = "sim"\ncontrol = "{control}"\ntelemetry = "{telemetry}"\n'
        f'store = "{home}/station/station.sqlite"\nreports = "{home}/station"\n'
    )
    proc = station_cli("panel", "--config", str(config), stdout=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(200):
            with contextlib.suppress(httpx2.TransportError):
                reply = httpx2.post(url + "/api/login", json={"username": "bench", "password": PASSWORD})
                break
            time.sleep(0.1)
        headers = {"Cookie": f"{SESSION_COOKIE}={reply.cookies[SESSION_COOKIE]}", CSRF_HEADER: reply.json()["csrf"]}
        yield Panel(url, proc.pid, headers)
    finally:
        stop(proc)


@contextlib.contextmanager
def served_station(home: Path, speed: float = 1000.0) -> Iterator[tuple[str, str]]:
    control, telemetry = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    proc = station_cli("serve", "--out", str(home / "station"), "--name", "sim", "--control", control,
                       "--telemetry", telemetry, "--speed", str(speed), stdout=subprocess.PIPE, text=True)  # fmt: skip
    proc.stdout.readline()
    try:
        yield control, telemetry
    finally:
        stop(proc)


@dataclass
class Browser:
    """What one WebSocket client received."""

    latencies_s: list[float] = field(default_factory=list)
    messages: int = 0
    samples: int = 0
    dropped: int = 0  # the panel's count for this browser
    seq_gaps: int = 0
    last_seq: int | None = None

    def take(self, frame: str | bytes, now: float) -> None:
        for doc in json.loads(frame):
            if doc["topic"] == "relay":
                self.dropped = doc["data"]["dropped"]
                continue
            self.messages += 1
            self.latencies_s.append(now - doc["wall_s"])
            if doc["topic"] == "trace":
                self.samples += len(doc["data"]["z_m"])
            if self.last_seq is not None and doc["seq"] > self.last_seq + 1:
                self.seq_gaps += doc["seq"] - self.last_seq - 1
            self.last_seq = max(doc["seq"], self.last_seq or 0)


async def browse(panel: Panel, browser: Browser, done: asyncio.Event) -> None:
    url = panel.url.replace("http", "ws") + "/ws/telemetry"
    async with connect(url, additional_headers=panel.headers | {"Origin": panel.url}, max_size=None) as ws:
        while not done.is_set():
            with contextlib.suppress(TimeoutError):
                browser.take(await asyncio.wait_for(ws.recv(), 0.5), time.time())


async def stall(panel: Panel, done: asyncio.Event) -> None:
    """A browser that never reads: its client stops reading the socket once 16 frames wait, and (like a browser)
    sends no pings of its own; the panel drops its backlog, and closes it when its pings go unanswered."""
    url = panel.url.replace("http", "ws") + "/ws/telemetry"
    with contextlib.suppress(ConnectionClosed, TimeoutError):
        async with connect(url, additional_headers=panel.headers | {"Origin": panel.url}, ping_interval=None,
                           close_timeout=1):  # fmt: skip
            await done.wait()


@dataclass
class Watched:
    browsers: list[Browser]  # the reading ones
    seconds: float
    panel_cpu_s: float
    clients_cpu_s: float  # this process: the browsers' JSON parsing


def summary(w: Watched, seconds: float | None = None) -> dict:
    """Latency over every message every browser got; rates per `seconds` (default: the whole watch)."""
    lat = np.array([x for b in w.browsers for x in b.latencies_s])
    browsers, seconds = w.browsers, seconds or w.seconds
    ms = {
        "median": float(np.median(lat) * 1e3),
        "p99": float(np.percentile(lat, 99) * 1e3),
        "max": float(lat.max() * 1e3),
    }
    return {
        "clients": len(browsers),
        "seconds": round(seconds, 1),
        "latency_ms": ms,
        "panel_cpu_percent": 100 * w.panel_cpu_s / seconds,
        "clients_cpu_percent": 100 * w.clients_cpu_s / seconds,
        "messages_per_s_per_client": statistics.mean(b.messages for b in browsers) / seconds,
        "samples_per_s_per_client": statistics.mean(b.samples for b in browsers) / seconds,
        "samples_per_s_all_clients": sum(b.samples for b in browsers) / seconds,
        "dropped": sum(b.dropped for b in browsers),
        "seq_gaps": sum(b.seq_gaps for b in browsers),
        "load_average_1min": os.getloadavg()[0],  # the machine is shared: other work competes for the 2 cores
    }


async def watch(panel: Panel, clients: int, run, silent: int = 0) -> Watched:
    """Connect the browsers (`silent` of them never read), await run(), then close."""
    done = asyncio.Event()
    readers = [Browser() for _ in range(clients - silent)]
    tasks = [asyncio.create_task(browse(panel, b, done)) for b in readers]
    tasks += [asyncio.create_task(stall(panel, done)) for _ in range(silent)]
    await asyncio.sleep(1.0)  # connected, the replay of the present state received
    for b in readers:
        b.latencies_s.clear()
        b.messages = b.samples = 0
    t0, cpu0, mine0 = time.monotonic(), panel.cpu_s(), time.process_time()
    await run()
    w = Watched(readers, time.monotonic() - t0, panel.cpu_s() - cpu0, time.process_time() - mine0)
    done.set()
    await asyncio.gather(*tasks)
    return w


async def run_session(panel: Panel, outcome: dict) -> None:
    """The default procedure (seed 000's 40 points), started through the panel; until the station is idle again."""
    await asyncio.to_thread(panel.post, "/api/stations/sim/start", {"procedure": "integral_precession"})
    while (status := await asyncio.to_thread(panel.status))["busy"]:
        await asyncio.sleep(0.5)
    outcome.update(state=status["state"], faults=status["faults"], done=status["done"], total=status["total"])


def bench_station(clients: int) -> dict:
    outcome: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        home = Path(tmp)
        with served_station(home) as (control, telemetry), panel_for(telemetry, control, home) as panel:
            return summary(asyncio.run(watch(panel, clients, lambda: run_session(panel, outcome)))) | outcome


def publish(endpoint: str, rate_hz: float, seconds: float) -> None:
    """The synthetic station: trace messages of TRACE_SAMPLES samples at rate_hz, and the 5/s status beacon."""
    from station.clock import WallClock
    from station.telemetry import TelemetryPublisher

    pub = TelemetryPublisher(endpoint, "sim", WallClock())
    t = np.arange(TRACE_SAMPLES) / 5000.0
    z = 0.03 * np.sin(2 * np.pi * 10 * t)
    t0 = time.monotonic()
    n = 0
    while (elapsed := time.monotonic() - t0) < seconds:
        if n % max(1, round(rate_hz / 5)) == 0:
            pub.publish("status", {"state": "running", "fraction": elapsed / seconds})
        pub.publish("trace", {"t_s": t + elapsed, "z_m": z, "freq_hz": 10.0})
        n += 1
        time.sleep(max(0.0, t0 + n / rate_hz - time.monotonic()))
    pub.close()


def bench_stress(clients: int, rates: list[float]) -> list[dict]:
    out = []
    for rate in rates:
        with tempfile.TemporaryDirectory() as tmp:
            endpoint = f"tcp://127.0.0.1:{free_port()}"
            with panel_for(endpoint, "tcp://127.0.0.1:1", Path(tmp)) as panel:

                async def run(rate=rate, endpoint=endpoint):
                    args = ["--publish", endpoint, "--rate", str(rate), "--seconds", str(STRESS_S)]
                    proc = await asyncio.create_subprocess_exec(sys.executable, __file__, *args)
                    await proc.wait()
                    await asyncio.sleep(0.5)  # the last messages on their way

                row = summary(asyncio.run(watch(panel, clients, run)), STRESS_S)
        row["offered_samples_per_s"] = rate * TRACE_SAMPLES
        out.append(row)
        print(f"stress {rate:g} msg/s: {json.dumps(row)}", file=sys.stderr)
    return out


def bench_memory(clients: int, speed: float) -> dict:
    outcome: dict = {}
    relay: dict = {}
    samples: list[tuple[float, float]] = []
    with tempfile.TemporaryDirectory() as tmp:
        home = Path(tmp)
        with served_station(home, speed) as (control, telemetry), panel_for(telemetry, control, home) as panel:

            async def run():
                t0 = time.monotonic()

                async def sample():
                    while True:
                        samples.append((time.monotonic() - t0, panel.rss_mb()))
                        await asyncio.sleep(RSS_EVERY_S)

                sampler = asyncio.create_task(sample())
                await run_session(panel, outcome)
                sampler.cancel()
                relay.update(httpx2.get(panel.url + "/api/relay", headers=panel.headers).json())

            watched = asyncio.run(watch(panel, clients, run, silent=1))
    t, rss = np.array(samples).T
    half = t >= t[-1] / 2
    return {
        "speed": speed,
        "minutes": round(watched.seconds / 60, 1),
        "clients": clients,
        "never_reading": 1,
        "relay_at_end": relay,  # browsers connected at the end; messages dropped for the one that never read
        "rss_mb_first": float(rss[0]),
        "rss_mb_after_first_minute": float(rss[t >= 60][0]),
        "rss_mb_last": float(rss[-1]),
        "rss_mb_max": float(rss.max()),
        "rss_slope_mb_per_min_second_half": float(np.polyfit(t[half], rss[half], 1)[0] * 60),
        "relayed": summary(watched),
    } | outcome


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clients", type=int, default=10)
    p.add_argument("--stress-rates", type=float, nargs="*", default=[50, 100, 200, 300, 400])
    p.add_argument("--memory-speed", type=float, default=50.0, help="0: no memory run")
    p.add_argument("--publish", help=argparse.SUPPRESS)  # the synthetic station's own process
    p.add_argument("--rate", type=float, help=argparse.SUPPRESS)
    p.add_argument("--seconds", type=float, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.publish:
        publish(args.publish, args.rate, args.seconds)
        return 0
    result = {"machine": f"{os.cpu_count()} cores {platform.machine()}, Python {platform.python_version()}"}
    result["station"] = bench_station(args.clients)
    print(f"station: {json.dumps(result['station'])}", file=sys.stderr)
    result["stress"] = bench_stress(args.clients, args.stress_rates)
    if args.memory_speed > 0:
        result["memory"] = bench_memory(args.clients, args.memory_speed)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
