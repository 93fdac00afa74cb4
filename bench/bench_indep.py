"""Speed of the independent session generator (tests/indep, issue 10 d4/d5).

For each design family and case kind, `make_case` is timed over seeds 0..N-1 (one process,
BLAS pinned to one thread); the table gives the median and maximum CPU seconds per case (process
time: on a shared machine wall time measures the neighbours' load), the median wall seconds, the
median number of points (windows) and the median CPU time per window, without and with raw
records. A "typical" case is a library effect scaled to its SNR (the noise-free session is
simulated 2-4 times by the SNR scaling, then once with noise).

    .venv/bin/python bench/bench_indep.py [N]        (cases per family and kind)
    .venv/bin/python bench/bench_indep.py --large    (null sessions of 40, 160, 640 points)

Simulation path: neither the engine nor session_sim: tests/indep's independent generator.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402
from indep.cases import FAMILIES, LIBRARY, make_case  # noqa: E402
from indep.generator import Truth, equal_angle_design, random_coefficients, random_noise, write_session  # noqa: E402

KINDS = ("null", "library", "pair", "ool")


def _kind(k: str, seed: int) -> str:
    if k == "library":
        return LIBRARY[seed % len(LIBRARY)]
    if k == "pair":
        return f"pair:{LIBRARY[seed % len(LIBRARY)]}+{LIBRARY[(seed + 3) % len(LIBRARY)]}"
    if k == "ool":
        return "ool:bias_step"
    return "null"


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 and sys.argv[1].isdigit() else 10
    print("| family | kind | raw | median CPU s/case | max CPU s/case | median wall s | median points | CPU ms/point |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for family in FAMILIES:
            for kind in KINDS:
                for raw in (False, True):
                    if raw and kind not in ("null", "library"):
                        continue
                    times, walls, points = [], [], []
                    for seed in range(n):
                        t0, c0 = time.perf_counter(), time.process_time()
                        truth = make_case(seed, _kind(kind, seed), Path(tmp) / "c", snr=10.0, family=family, raw=raw)
                        times.append(time.process_time() - c0)
                        walls.append(time.perf_counter() - t0)
                        points.append(truth["n_points"])
                    per = statistics.median(t / p for t, p in zip(times, points, strict=True))
                    print(
                        f"| {family} | {kind} | {raw} | {statistics.median(times):.2f} | {max(times):.2f} | "
                        f"{statistics.median(walls):.2f} | {statistics.median(points):.0f} | {1e3 * per:.1f} |",
                        flush=True,
                    )


def large() -> None:
    """Null sessions of 40, 160 and 640 points (equal-angle, 9 frequencies, windows up to an hour)."""
    print("| points | positions | raw | CPU s | wall s | CPU ms/point |")
    print("| --- | --- | --- | --- | --- | --- |")
    freqs = (1.0, 2.0, 3.5, 4.0, 5.25, 6.0, 7.5, 8.0, 10.0)
    with tempfile.TemporaryDirectory() as tmp:
        for n_pos in (4, 16, 64):
            for raw in (False, True):
                rng = np.random.default_rng(n_pos)
                design = equal_angle_design(n_pos, freqs, window_revs=20, max_window_s=3600.0)
                truth = Truth(random_coefficients(rng), noise=random_noise(rng))
                t0, c0 = time.perf_counter(), time.process_time()
                rows = write_session(Path(tmp) / "s", design, truth, rng, raw=raw)
                cpu, wall = time.process_time() - c0, time.perf_counter() - t0
                print(
                    f"| {len(rows)} | {n_pos} | {raw} | {cpu:.2f} | {wall:.2f} | {1e3 * cpu / len(rows):.1f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main() if "--large" not in sys.argv else large()
