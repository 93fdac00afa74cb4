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

`--cli` times `station gap SESSION --json OUT` as a user runs it, start-up included (a child process: its user +
system CPU from getrusage), on tests/indep's 640-point null sessions (64 equal-angle positions x 9 frequencies
with non-integer ones + static, windows to an hour; seed 700 without raw records or stated noise, 701 with both),
median of three runs each, in the caller's environment (BLAS threads as the user has them); `--code DIR` runs
the code of another checkout (the figure before a change).

    .venv/bin/python bench/bench_gap.py [--sizes-only]
    .venv/bin/python bench/bench_gap.py --cli [--code /path/to/other/checkout]

Simulation path: the session_sim shortcut (not the engine): station.twin.session_sim (station.gap.validate's generator),
sessions
to diagnose; `--cli` reads tests/indep's sessions (the independent generator, neither path).
"""

from __future__ import annotations

import os

USER_ENV = dict(os.environ)  # what `station gap` runs with (--cli): BLAS threads as the user has them
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import json  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

REPEATS = 5
CASES = (("null", None), ("effect", "cross_coupling"), ("out_of_library", "bias_step"))


def _time(session, twin, suggest: bool) -> tuple[float, float, str]:
    from station.gap.api import diagnose

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
    from station.twin.plan import equal_angle_positions_deg, multiposition_plan, seed000_plan
    from station.twin.session_sim import simulate_session

    plan160 = multiposition_plan(equal_angle_positions_deg(16), SIZE_FREQS_HZ, window_s=60.0)
    plan640 = multiposition_plan(equal_angle_positions_deg(64), SIZE_FREQS_HZ, window_s=60.0)
    for label, plan in (("40", seed000_plan()), ("160", plan160), ("640 (160 x 4)", plan160 * 4), ("640", plan640)):
        yield label, simulate_session(plan, twin, 5)


CLI_SEEDS = (700, 701)
CLI_FREQS_HZ = (1.0, 2.0, 3.5, 4.0, 5.25, 6.0, 7.5, 8.0, 10.0)


def _write_640(seed: int, where: Path) -> None:
    """tests/indep's 640-point null of bench_gap_indep --large-nulls (seed odd: raw records and noise stated)."""
    import numpy as np

    sys.path.append(str(ROOT / "tests"))
    from indep.generator import Truth, equal_angle_design, random_coefficients, random_noise, write_session

    rng = np.random.default_rng([seed, 64])
    design = equal_angle_design(64, CLI_FREQS_HZ, window_revs=20, max_window_s=3600.0)
    truth = Truth(random_coefficients(rng), noise=random_noise(rng))
    write_session(where, design, truth, rng, raw=bool(seed % 2), state_noise=bool(seed % 2))


def _child_cpu_s(cmd: list[str], env: dict, cwd: Path) -> tuple[float, float]:
    """User + system CPU seconds of one child process run to its end, and its wall time."""
    before, w = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    subprocess.run(cmd, env=env, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, time.perf_counter() - w


def cli_runs(code: Path, repeats: int = 3) -> None:
    """`station gap` on the 640-point nulls, start-up included, with the code of checkout `code`."""
    env = dict(USER_ENV, PYTHONPATH=str(code))
    with tempfile.TemporaryDirectory(prefix="bench_gap_cli_") as tmp:
        for seed in CLI_SEEDS:
            session = Path(tmp) / f"s{seed}"
            _write_640(seed, session)
            out = Path(tmp) / f"r{seed}.json"
            cmd = [sys.executable, "-m", "station.cli.cli", "gap", str(session), "--json", str(out)]
            runs = [_child_cpu_s(cmd, env, code) for _ in range(repeats)]  # python -m: the cwd comes first
            verdict = json.loads(out.read_text())["verdict"]
            row = {"seed": seed, "points": 640, "code": str(code), "verdict": verdict}
            row["cpu_s"] = [round(c, 2) for c, _ in runs]
            row["median_cpu_s"] = round(statistics.median(c for c, _ in runs), 2)
            row["median_wall_s"] = round(statistics.median(w for _, w in runs), 2)
            print(json.dumps(row), flush=True)


def main() -> None:
    if "--cli" in sys.argv:
        code = Path(sys.argv[sys.argv.index("--code") + 1]) if "--code" in sys.argv else ROOT
        cli_runs(code.resolve())
        return
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    from station.gap.api import diagnose
    from station.gap.validate import Case, make_session
    from station.twin.config import default_twin

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
