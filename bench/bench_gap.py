"""Gap-diagnosis speed on one core: 40-point seed-000 sessions, and sessions of 40, 160 and 640 points
(goal: a 640-point session under 10 s, issue 10 point 7; cost linear in points).

Null, in-library (cross_coupling) and out-of-library (bias_step) sessions at SNR 10,
each diagnosed as `station gap` does (with the search for separating test
points) and without that search; median of REPEATS runs after a warm-up. BLAS
threads are pinned to one before numpy loads, and the process to one core
where the OS allows it.

Sizes: 16 equal-angle positions x (9 frequencies in 2-10 Hz + static), 60 s windows = 160 points,
repeated 4 times = 640 points (160 distinct position x frequency cases), 64 positions x the same =
640 points all distinct; and the 40-point seed-000 design. CPU seconds are the figure to quote
on a shared machine (wall time includes other processes' load).

    .venv/bin/python bench/bench_gap.py [--sizes-only]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import json  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

REPEATS = 5
CASES = (("null", None), ("effect", "cross_coupling"), ("out_of_library", "bias_step"))


def _time(session, twin, suggest: bool) -> tuple[float, float, str]:
    from gap.api import diagnose

    walls, cpus = [], []
    for _ in range(REPEATS):
        w, c = time.perf_counter(), time.process_time()
        report = diagnose(session, twin, suggest=suggest)
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return statistics.median(walls), statistics.median(cpus), report.verdict.verdict


SIZE_FREQS_HZ = (2.0, 3.5, 5.0, 6.0, 7.0, 8.0, 8.5, 9.0, 10.0)


def size_sessions(twin):
    """(label, session) of 40, 160 and 640 points (module docstring)."""
    from models.plan import equal_angle_positions_deg, multiposition_plan, seed000_plan
    from models.session_sim import simulate_session

    plan160 = multiposition_plan(equal_angle_positions_deg(16), SIZE_FREQS_HZ, window_s=60.0)
    plan640 = multiposition_plan(equal_angle_positions_deg(64), SIZE_FREQS_HZ, window_s=60.0)
    for label, plan in (("40", seed000_plan()), ("160", plan160), ("640 (160 x 4)", plan160 * 4), ("640", plan640)):
        yield label, simulate_session(plan, twin, 5)


def main() -> None:
    import sys

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    from gap.api import diagnose
    from gap.validate import Case, make_session
    from models.config import default_twin

    twin = default_twin()
    rows = []
    for n, session in size_sessions(twin):
        for suggest in (False, True):
            w, c = time.perf_counter(), time.process_time()
            report = diagnose(session, twin, suggest=suggest)
            row = {"points": n, "separating_search": suggest, "verdict": report.verdict.verdict}
            row["distinct_cases"] = len({(p.position_deg, p.freq_hz) for p in session.points})
            row |= {"wall_s": round(time.perf_counter() - w, 2), "cpu_s": round(time.process_time() - c, 2)}
            print(json.dumps(row), flush=True)
    if "--sizes-only" in sys.argv:
        return
    for kind, effect in CASES:
        session, _ = make_session(Case("seed000", kind, effect, 10.0, 7), twin)
        diagnose(session, twin)  # warm-up
        for suggest in (True, False):
            wall, cpu, verdict = _time(session, twin, suggest)
            rows.append(
                {
                    "session": f"{kind} {effect or ''}".strip(),
                    "points": len(session.points),
                    "separating_search": suggest,
                    "verdict": verdict,
                    "wall_s": round(wall, 3),
                    "cpu_s": round(cpu, 3),
                }
            )
            print(json.dumps(rows[-1]))
    machine = {"machine": platform.machine(), "cores": os.cpu_count(), "python": platform.python_version()}
    print(json.dumps(machine))


if __name__ == "__main__":
    main()
