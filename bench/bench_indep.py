"""Speed of the independent session generator (tests/indep, issue 10 d4/d5).

For each design family and case kind, `make_case` is timed over seeds 0..N-1 (wall clock, one
process, BLAS pinned to one thread); the table gives the median and maximum seconds per case,
the median number of points (windows) and the median time per window, without and with raw
records. A "typical" case is a library effect scaled to its SNR (the noise-free session is
simulated 2-4 times by the SNR scaling, then once with noise).

    .venv/bin/python bench/bench_indep.py [N]
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

from indep.cases import FAMILIES, LIBRARY, make_case  # noqa: E402

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
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    print("| family | kind | raw | median s/case | max s/case | median points | median ms/point |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for family in FAMILIES:
            for kind in KINDS:
                for raw in (False, True):
                    if raw and kind not in ("null", "library"):
                        continue
                    times, points = [], []
                    for seed in range(n):
                        t0 = time.perf_counter()
                        truth = make_case(seed, _kind(kind, seed), Path(tmp) / "c", snr=10.0, family=family, raw=raw)
                        times.append(time.perf_counter() - t0)
                        points.append(truth["n_points"])
                    per = statistics.median(t / p for t, p in zip(times, points, strict=True))
                    print(
                        f"| {family} | {kind} | {raw} | {statistics.median(times):.2f} | {max(times):.2f} | "
                        f"{statistics.median(points):.0f} | {1e3 * per:.1f} |",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
