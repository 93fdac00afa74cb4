"""False alarms of the gap diagnosis on null sessions from generators other than the twin (issue 28, d3).

Null sessions (no effect) of tests/indep (`indep.cases.make_case(seed, "null")`: its four design families,
raw records or not, rate noise 2e-7..5e-6 rad/s per-window or white, timing noise 5e-8..2e-7 s, noise stated
in session.json or not, every third seed without the stamps' resolution) and the null cases of
../shared/gap-devset, diagnosed blind against the default twin. Per case: the verdict and every residual
test's p-value before any effect (station.gap.localise; the goodness-of-fit tests of the rate, timing, pulse and grating
channels among them). Scores:

- family-wise false alarms: a verdict other than `no_gap` (the structure tests, the excess-scatter check and
  the candidates' significance together; the verdict corrects each family for multiplicity);
- per test: the fraction of nulls on which it is significant at the verdict's Bonferroni level
  (station.gap.verdict.family_level(n) / n), and at the nominal 0.01 and 0.05 (a calibration check of its p-value),
  per generator (indep, devset).

    .venv/bin/python bench/bench_gap_nulls.py --n 80 --workers 2 --out /tmp/nulls.jsonl
    .venv/bin/python bench/bench_gap_nulls.py --summarise /tmp/nulls.jsonl   # the scores of a run again

BLAS threads are limited to one per worker (threadpoolctl).

Simulation path: neither the engine nor session_sim: tests/indep's generator and ../shared/gap-devset.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import defaultdict
from multiprocessing import get_context
from pathlib import Path

from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]
sys.path += [str(ROOT / "tests")]  # indep lives under tests/, after the project's own packages
DEVSET = ROOT.parent / "shared" / "gap-devset"
NOMINAL = (0.01, 0.05)


def _diagnosed(session_dir: Path) -> dict:
    from station.gap.api import diagnose
    from station.gap.verdict import family_level
    from station.interchange import read_session
    from station.twin.config import default_twin

    rep = diagnose(read_session(session_dir), default_twin(), suggest=False)
    tests = rep.where["structure_tests_before"]
    level = family_level(len(tests)) / max(len(tests), 1)
    return {
        "verdict": rep.verdict.verdict,
        "named": rep.effects + rep.verdict.ambiguous + rep.verdict.partial,
        "level": level,
        "p_values": {t["name"]: t["p_value"] for t in tests if t["p_value"] is not None},
        "text": rep.verdict.text[:300],
    }


def run_case(case: tuple[str, int, str | None, bool | None]) -> dict:
    """One null session: ("indep", seed, family, raw) written by tests/indep, or ("devset", 0, case_id, None)."""
    threadpool_limits(1)
    source, seed, which, raw = case
    row: dict = {"source": source, "seed": seed, "case": which, "raw": raw}
    if source == "devset":
        return row | _diagnosed(DEVSET / "cases" / str(which))
    from indep.cases import make_case

    with tempfile.TemporaryDirectory(prefix="gap_nulls_") as tmp:
        truth = make_case(seed, "null", Path(tmp) / "s", family=which, raw=raw)
        row["stated_noise"] = truth["noise"]["stated"]
        row["resolution_stated"] = _drop_resolution(Path(tmp) / "s") if seed % 3 == 0 else row["stated_noise"]
        return row | _diagnosed(Path(tmp) / "s")


def _drop_resolution(session_dir: Path) -> bool:
    """Every third null states its timing jitter without the counter's resolution (the stamps are still counted
    in 50 ns ticks): the timing tests must then take the quantum from the station. False: none is stated."""
    meta_path = session_dir / "session.json"
    meta = json.loads(meta_path.read_text())
    meta.get("timing", {}).pop("timer_resolution_s", None)
    meta_path.write_text(json.dumps(meta))
    return False


def case_list(n: int, seed0: int) -> list[tuple[str, int, str | None, bool | None]]:
    """n indep nulls over the families, raw records on every other one, and the devset's nulls."""
    from indep.cases import FAMILIES

    out: list[tuple[str, int, str | None, bool | None]] = [
        ("indep", seed0 + k, FAMILIES[k % len(FAMILIES)], bool((k // len(FAMILIES)) % 2)) for k in range(n)
    ]
    if (DEVSET / "truth" / "_index.json").is_file():
        index = json.loads((DEVSET / "truth" / "_index.json").read_text())
        out += [("devset", 0, r["case_id"], None) for r in index if r["effect"] == "none"]
    return out


def _per_test(rows: list[dict]) -> dict:
    """Per test: how many nulls ran it, and on how many it is significant at the verdict's level and at NOMINAL."""
    out: dict[str, dict] = defaultdict(lambda: defaultdict(int))
    for r in rows:
        for name, p in r["p_values"].items():
            out[name]["n"] += 1
            out[name]["at_verdict_level"] += p < r["level"]
            for a in NOMINAL:
                out[name][f"at_{a:g}"] += p < a
    return {name: dict(v) for name, v in sorted(out.items())}


def summarise(rows: list[dict]) -> dict:
    """Family-wise false alarms, and each test's rate at the verdict's level and at NOMINAL, per generator."""
    alarms = [r for r in rows if r["verdict"] != "no_gap"]
    by_source = {
        src: {"nulls": len(sub), "not_no_gap": sum(r["verdict"] != "no_gap" for r in sub), "per_test": _per_test(sub)}
        for src in sorted({r["source"] for r in rows})
        for sub in [[r for r in rows if r["source"] == src]]
    }
    return {
        "nulls": len(rows),
        "family_wise_false_alarms": {"n": len(alarms), "rate": round(len(alarms) / max(len(rows), 1), 3)},
        "alarms": [{k: r[k] for k in ("source", "seed", "case", "raw", "verdict", "named", "text")} for r in alarms],
        "by_generator": by_source,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=80, help="indep null sessions")
    p.add_argument("--seed", type=int, default=900_000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, help="JSON lines, one per case")
    p.add_argument("--summarise", type=Path, help="only score the JSON lines of an earlier run")
    args = p.parse_args(argv)
    if args.summarise:
        print(json.dumps(summarise([json.loads(x) for x in args.summarise.read_text().splitlines()]), indent=1))
        return 0
    if args.out is None:
        p.error("--out is required")
    rows = []
    with args.out.open("w") as f, get_context("fork").Pool(args.workers) as pool:
        for row in pool.imap_unordered(run_case, case_list(args.n, args.seed), chunksize=1):
            rows.append(row)
            f.write(json.dumps(row) + "\n")
            f.flush()
            print(f"{row['source']} {row['seed']} {row['case']} raw {row['raw']}: {row['verdict']}", file=sys.stderr)
    print(json.dumps(summarise(rows), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
