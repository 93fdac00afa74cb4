"""Issue 30 (7): the longer fuzz campaign over import directories and procedure files, counted for BENCHMARKS.md.

    .venv/bin/python bench/fuzz_imports.py --imports 4000 --procedures 4000 --seed 30

Runs the cases of tests/test_fuzz_imports.py (the same mutations, oracles and runners: `import_case`,
`procedure_case`) in turn over every mutation with seeds from one random.Random(seed), and prints, per mutation and
in total: cases, clean refusals, accepted, tracebacks, accepted invalid inputs, store changes on refusal, and the
process's peak memory (ru_maxrss). The first few tracebacks and accepted invalid inputs are listed to reproduce
(mutation and case seed).

Simulation path: the lawful session every import case mutates is the session_sim shortcut (not the engine):
station.twin.session_sim, data to mutate.
"""

from __future__ import annotations

import argparse
import os
import platform
import random
import resource
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]  # the project first: tests/devices (a namespace) must not shadow devices
sys.path.append(str(ROOT / "tests"))

from test_fuzz_imports import (  # noqa: E402
    IMPORT_MUTATIONS,
    PROCEDURE_MUTATIONS,
    Outcome,
    import_case,
    make_bases,
    procedure_case,
)

COUNTS = ("cases", "refused", "accepted", "tracebacks", "accepted invalid", "store changes on refusal")


def _count(c: Counter, o: Outcome) -> None:
    c["cases"] += 1
    c[{"refused": "refused", "accepted": "accepted", "traceback": "tracebacks"}[o.kind]] += 1
    c["accepted invalid"] += bool(o.defects)
    c["store changes on refusal"] += o.store_changed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--imports", type=int, default=4000, help="import cases (default 4000)")
    ap.add_argument("--procedures", type=int, default=4000, help="procedure-file cases (default 4000)")
    ap.add_argument("--seed", type=int, default=30)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    rows: dict[str, Counter] = {}
    problems: list[str] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        bases = make_bases(Path(tmp) / "bases")
        work = Path(tmp) / "work"
        work.mkdir()
        for i in range(args.imports):
            m = IMPORT_MUTATIONS[i % len(IMPORT_MUTATIONS)]
            seed = rng.randrange(2**32)
            o = import_case(bases, work, work / "store.sqlite", m, seed)
            _count(rows.setdefault(f"import: {m.name}", Counter()), o)
            if o.kind == "traceback" or o.defects or o.store_changed:
                problems.append(f"import {m.name!r} seed {seed}: {o.kind} {o.detail[:160]} {o.defects[:2]}")
        for i in range(args.procedures):
            index = i % len(PROCEDURE_MUTATIONS)
            seed = rng.randrange(2**32)
            o = procedure_case(work, index, seed)
            _count(rows.setdefault(f"procedure file: {PROCEDURE_MUTATIONS[index][0]}", Counter()), o)
            if o.kind == "traceback" or o.defects:
                problems.append(f"procedure {PROCEDURE_MUTATIONS[index][0]!r} seed {seed}: {o.kind} {o.detail[:160]} "
                                f"{o.defects[:2]}")  # fmt: skip
    wall = time.perf_counter() - t0
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
          f"seed {args.seed}; {wall:.0f} s wall; peak memory (ru_maxrss) {peak_mib:.0f} MiB")  # fmt: skip
    print("| mutation | " + " | ".join(COUNTS) + " |")
    print("|---|" + "---:|" * len(COUNTS))
    total: Counter = Counter()
    for name, c in rows.items():
        total += c
        print(f"| {name} | " + " | ".join(str(c[k]) for k in COUNTS) + " |")
    for group in ("import", "procedure file"):
        t = sum((c for n, c in rows.items() if n.startswith(group + ":")), Counter())
        print(f"| **all {group} cases** | " + " | ".join(str(t[k]) for k in COUNTS) + " |")
    for p in problems[:20]:
        print(p)
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
