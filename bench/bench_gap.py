"""Gap-diagnosis speed: a 40-point seed-000 session diagnosed on one core (goal: under 10 s, issue 3 point 7).

Null, in-library (cross_coupling) and out-of-library (bias_step) sessions at SNR 10,
each diagnosed as `station gap` does (with the search for separating test
points) and without that search; median of REPEATS runs after a warm-up. BLAS
threads are pinned to one before numpy loads, and the process to one core
where the OS allows it.

    .venv/bin/python bench/bench_gap.py
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


def main() -> None:
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    from gap.api import diagnose
    from gap.validate import Case, make_session
    from models.config import default_twin

    twin = default_twin()
    rows = []
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
