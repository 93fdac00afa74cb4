"""The gap diagnosis scored on ../shared/gap-devset: 29 sessions from an implementation of physics.md that
shares no code with the project, with their truth (issue 28, deliverable 1).

Each case directory is read through station.interchange and diagnosed blind against the default twin
(`suggest=False`, as a batch would). What counts as right is the devset README's:

- a library effect at SNR >= 10 (truth `snr_primary`, the strongest channel's): `explained` with it first, or
  `cannot_tell` naming it together with at least one look-alike;
- a pair: `explained` naming both, or `cannot_tell` naming both (scored: both named among the effects, the
  partial and the ambiguous, and the verdict `explained` or `cannot_tell`);
- a null session: `no_gap`;
- an effect outside physics.md's table: never `explained`.

Library effects below SNR 10 are reported, not scored against the target. One JSON line per case (--out),
then the scores:

    .venv/bin/python bench/bench_gap_devset.py --workers 2 --out /tmp/devset.jsonl

BLAS threads are pinned to one per worker.

Simulation path: neither the engine nor session_sim: ../shared/gap-devset's sessions, read from disk.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from multiprocessing import get_context  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DEVSET = ROOT.parent / "shared" / "gap-devset"
TARGETS = {"right_at_snr_ge10": 0.95, "pairs_named": 0.8, "nulls_not_no_gap": 0.05, "ool_explained": 0.10}


def case_ids(devset: Path = DEVSET) -> list[str]:
    """Every case of the set, in the order of its index."""
    return [r["case_id"] for r in json.loads((devset / "truth" / "_index.json").read_text())]


def run_case(case_id: str, devset: Path = DEVSET) -> dict:
    """Diagnose one case blind and return one JSON-able line with its truth and the verdict."""
    from station.gap.api import diagnose
    from station.interchange import read_session
    from station.twin.config import default_twin

    truth = json.loads((devset / "truth" / f"{case_id}.json").read_text())
    effect = truth["effect"]
    c0 = time.process_time()
    rep = diagnose(read_session(devset / "cases" / case_id), default_twin(), suggest=False)
    j = rep.to_json()
    tests = j["where"]["structure_tests_after" if rep.effects or rep.verdict.partial else "structure_tests_before"]
    return {
        "case_id": case_id,
        "truth": effect if isinstance(effect, list) else ([] if effect == "none" else [effect]),
        "in_library": bool(truth["in_library"]),
        "snr_primary": float(truth["snr"]["snr_primary"]),
        "channel": truth["snr"]["snr_primary_channel"],
        "n_positions": truth["design"]["n_positions"],
        **{k: getattr(rep.verdict, k) for k in ("verdict", "effects", "ambiguous", "partial", "text")},
        "rejecting_tests": [
            {"name": t["name"], "p_value": t["p_value"]}
            for t in tests
            if t["p_value"] is not None and t["p_value"] < 1e-3
        ],
        "parameters": _parameters(j["candidates"], rep.effects + rep.verdict.ambiguous + rep.verdict.partial, truth),
        "n_points": j["session"]["n_points"],
        "cpu_s": round(time.process_time() - c0, 2),
    }


def _parameters(candidates: list[dict], named: list[str], truth: dict) -> dict:
    """Each named effect's fitted parameters where the truth injected that effect: value, sd, the truth's value
    of the same name (None where its parameters differ: lateral L0 against our kx) and the difference in sd."""
    out: dict = {}
    for c in candidates:
        injected = truth["effects"].get(c["name"])
        if c["name"] not in named or injected is None:
            continue
        out[c["name"]] = {k: _compared(v, c["uncertainty"][k], injected.get(k)) for k, v in c["parameters"].items()}
    return out


def _compared(value: float, sd: float, true: float | None) -> dict:
    z = None if true is None or not sd else round((value - true) / sd, 2)
    return {"value": value, "sd": sd, "truth": true, "z": z}


def kind(r: dict) -> str:
    """null, single (a library effect), pair, or ool (an effect outside physics.md's table)."""
    if not r["truth"]:
        return "null"
    if not r["in_library"]:
        return "ool"
    return "pair" if len(r["truth"]) > 1 else "single"


def right(r: dict) -> bool:
    """The devset README's rule for the case's kind."""
    k, v = kind(r), r["verdict"]
    if k == "null":
        return v == "no_gap"
    if k == "ool":
        return v != "explained"
    if k == "pair":
        named = set(r["effects"] + r["partial"] + r["ambiguous"])
        return v in ("explained", "cannot_tell") and set(r["truth"]) <= named
    eff = r["truth"][0]
    return (v == "explained" and r["effects"][:1] == [eff]) or (
        v == "cannot_tell" and eff in r["ambiguous"] and len(r["ambiguous"]) >= 2
    )


def _rate(rows: list[dict]) -> dict:
    n_right = sum(map(right, rows))
    return {"right": n_right, "n": len(rows), "rate": round(n_right / len(rows), 3) if rows else None}


def summarise(rows: list[dict]) -> dict:
    """Scores per kind against the issue's targets, and every case the truth and the diagnosis disagree on."""
    by = {k: [r for r in rows if kind(r) == k] for k in ("single", "pair", "null", "ool")}
    strong = [r for r in by["single"] if r["snr_primary"] >= 10.0]
    return {
        "targets": TARGETS,
        "cases": len(rows),
        "right_at_snr_ge10": _rate(strong),
        "right_below_snr10": _rate([r for r in by["single"] if r["snr_primary"] < 10.0]),
        "pairs_named": _rate(by["pair"]),
        "nulls_no_gap": _rate(by["null"]),
        "ool_not_explained": _rate(by["ool"]),
        "misses": [
            {k: r[k] for k in ("case_id", "truth", "snr_primary", "verdict", "effects", "ambiguous", "partial")}
            for r in rows
            if not right(r)
        ],
        "median_cpu_s": sorted(r["cpu_s"] for r in rows)[len(rows) // 2] if rows else None,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--devset", type=Path, default=DEVSET)
    p.add_argument("--cases", nargs="*", help="only these case ids")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, required=True, help="JSON lines, one per case")
    args = p.parse_args(argv)
    todo = args.cases or case_ids(args.devset)
    rows = []
    with args.out.open("w") as f, get_context("fork").Pool(args.workers) as pool:
        for row in pool.imap_unordered(_run_one, [(c, str(args.devset)) for c in todo], chunksize=1):
            rows.append(row)
            f.write(json.dumps(row) + "\n")
            f.flush()
            print(f"{row['case_id']} {row['truth']} snr {row['snr_primary']:.3g}: {row['verdict']} "
                  f"{row['effects'] or row['ambiguous'] or row['partial']} {'ok' if right(row) else 'MISS'}",
                  file=sys.stderr)  # fmt: skip
    print(json.dumps(summarise(rows), indent=1))
    return 0


def _run_one(arg: tuple[str, str]) -> dict:
    """run_case for a process pool (one picklable argument)."""
    return run_case(arg[0], Path(arg[1]))


if __name__ == "__main__":
    sys.exit(main())
