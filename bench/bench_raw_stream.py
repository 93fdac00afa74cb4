"""Raw streams streamed to HDF5: peak memory and time of a 40-point raw session (seed 000's plan, every pulse edge
and the 5 kHz grating of every window) through `station simulate --raw`, `station import` and `station export`.

    .venv/bin/python bench/bench_raw_stream.py [WORKDIR]

Each command runs under /usr/bin/time -v (peak resident set size of the process) in a fresh process. Figures:
BENCHMARKS.md, section "Raw streams in HDF5 (issue 14)".

Simulation path: the session_sim shortcut (not the engine): `station simulate --raw` (station.twin.session_sim).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STATION = str(Path(sys.executable).with_name("station"))


def measured(args: list[str]) -> tuple[float, float]:
    """(wall s, peak RSS MB) of one command."""
    t0 = time.perf_counter()
    run = subprocess.run(["/usr/bin/time", "-v", STATION, *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if run.returncode != 0:
        raise SystemExit(f"station {' '.join(args)} failed:\n{run.stderr[-2000:]}")
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", run.stderr).group(1))
    return wall, rss_kb / 1024


def size_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) / 2**20


def main() -> None:
    work = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="bench-raw-"))
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    sim, db, exported = work / "sim40", work / "station.sqlite", work / "exported"
    rows = [("simulate --raw (40 points)", *measured(["simulate", str(sim), "--raw"]), size_mb(sim))]
    rows.append(("import", *measured(["import", str(sim), "--db", str(db)]), size_mb(work / "station.sqlite.raw")))
    uid = subprocess.run([STATION, "sessions", "--db", str(db)], capture_output=True, text=True,
                         check=True).stdout.split()[0]  # fmt: skip
    rows.append(("export", *measured(["export", uid, str(exported), "--db", str(db)]), size_mb(exported)))
    print(f"{'command':28s} {'wall s':>8s} {'peak RSS MB':>12s} {'on disk MB':>11s}")
    for name, wall, rss, disk in rows:
        print(f"{name:28s} {wall:8.1f} {rss:12.0f} {disk:11.0f}")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
