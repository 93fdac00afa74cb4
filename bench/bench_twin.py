"""Twin speed: simulated station-seconds per wall-second, with and without raw streams.

(a) a full 40-point seed-000 session without raw streams (goal: under 1 s);
(b) one 560 s point with raw streams (5 kHz grating, every pulse edge, every
reference crossing): speed as a multiple of real time on one core (goal >= 1000)
and the peak memory of a process that simulates it (goal < 500 MB), measured in
a fresh child process each (ru_maxrss).

    .venv/bin/python bench/bench_twin.py

Simulation path: the session_sim shortcut (not the engine): this is the shortcut's own speed (station.twin.session_sim,
station.twin.measurement).
"""

from __future__ import annotations

import json
import platform
import resource
import statistics
import subprocess
import sys
import time


def session_speed(repeats: int = 7) -> dict:
    from station.twin.config import default_twin
    from station.twin.plan import seed000_plan
    from station.twin.session_sim import simulate_session

    cfg, plan = default_twin(), seed000_plan()
    simulate_session(plan, cfg, seed=0)  # warm-up
    walls, station = [], 0.0
    for seed in range(repeats):
        t = time.perf_counter()
        s = simulate_session(plan, cfg, seed=seed)
        walls.append(time.perf_counter() - t)
        station = sum(p.Tm_s for p in s.points)
    wall = statistics.median(walls)
    return {"wall_s": wall, "station_s": station, "speed": station / wall}


def _raw_point_child(freq_hz: float) -> None:
    import numpy as np

    from station.twin.config import default_twin
    from station.twin.measurement import simulate_point
    from station.twin.plan import PointSpec

    cfg = default_twin()
    simulate_point(PointSpec(0.0, freq_hz, 16384), cfg, np.random.default_rng(0), raw=True)  # warm-up, 11 s
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t = time.perf_counter()
    sp = simulate_point(PointSpec(0.0, freq_hz), cfg, np.random.default_rng(1), raw=True)
    wall = time.perf_counter() - t
    r = sp.raw
    print(
        json.dumps(
            {
                "freq_hz": freq_hz,
                "wall_s": wall,
                "station_s": sp.true_Tm_s,
                "speed": sp.true_Tm_s / wall,
                "edges": int(r.pulse_t.size),
                "grating": int(r.grating_t.size),
                "crossings": int(0 if r.reference_t is None else r.reference_t.size),
                "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                "warm_rss_mb": rss0 / 1024,
            }
        )
    )


def raw_point(freq_hz: float) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--child", str(freq_hz)], capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    a = session_speed()
    cpu = platform.processor() or platform.machine()
    print(f"machine: {cpu}, {platform.python_implementation()} {platform.python_version()}")
    print("\n| (a) 40-point seed-000 session, no raw | value |\n|---|---|")
    print(f"| wall time (median of 7) | {a['wall_s']:.3f} s |")
    print(f"| station time | {a['station_s']:.0f} s |")
    print(f"| speed | {a['speed']:.3g} station-s per wall-s |")
    print(
        "\n| (b) one point with raw streams | wall (s) | station (s) | x real time | pulse edges | edges/s"
        " | grating samples | peak RSS (MB) | RSS before the point (MB) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for f in (0.0, 8.0, 10.0):
        r = raw_point(f)
        label = "static" if f == 0 else f"{f:g} Hz"
        print(
            f"| {label} | {r['wall_s']:.3f} | {r['station_s']:.1f} | {r['speed']:.0f} | {r['edges']} | "
            f"{r['edges'] / r['station_s']:.0f} | {r['grating']} | {r['peak_rss_mb']:.0f} | {r['warm_rss_mb']:.0f} |"
        )


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        _raw_point_child(float(sys.argv[2]))
    else:
        main()
