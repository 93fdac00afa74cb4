"""Fan-out of cases on a local process pool and on a real dask.distributed cluster: same results in the same
order, one JSON line per finished case, resumption after an interruption."""

from __future__ import annotations

import json
import math

import pytest

from station.fanout import CaseLog, ExecutorSpec, FanoutError, run_cases
from station.gap.validate import main as validate_main

SQUARES = [float(k * k) for k in range(1, 9)]


def gap_cases(tmp_path, name: str, executor: list[str]) -> dict:
    """A blind run of 3 cheap cases (a null, an effect, an out-of-library term) through `station gap-validate`."""
    out, log = tmp_path / f"{name}.json", tmp_path / f"{name}.jsonl"
    args = ["--design", "seed000", "--snr", "10", "--reps", "1", "--nulls", "1", "--effects", "cross_coupling"]
    args += ["--out-of-library", "quartic_term", "--quiet", "--json", str(out), "--results", str(log), *executor]
    assert validate_main(args) == 0
    doc = json.loads(out.read_text())
    lines = log.read_text().splitlines()
    assert len(lines) == 1 + len(doc["cases"])  # the settings, then one line per case
    return doc


def test_gap_validate_verdicts_are_the_same_on_a_local_pool_and_on_a_dask_cluster(tmp_path, dask_scheduler, capsys):
    local = gap_cases(tmp_path, "local", ["--executor", "local", "--workers", "2"])
    dask = gap_cases(tmp_path, "dask", ["--executor", "dask", "--scheduler", dask_scheduler])
    assert [c["kind"] for c in local["cases"]] == ["null", "effect", "out_of_library"]

    def timeless(doc: dict) -> list[dict]:
        return [{k: v for k, v in c.items() if k != "elapsed_s"} for c in doc["cases"]]

    assert timeless(dask) == timeless(local)  # same seeds, same sessions, same verdicts, same order
    assert dask["settings"]["executor"] == "dask" and dask["settings"]["scheduler"] == dask_scheduler
    drop = ("median_diagnosis_s",)
    assert {k: v for k, v in dask["summary"]["seed000"].items() if k not in drop} == {
        k: v for k, v in local["summary"]["seed000"].items() if k not in drop
    }


def test_a_dask_executor_without_a_scheduler_starts_its_own_local_cluster():
    got = run_cases(math.sqrt, SQUARES, ExecutorSpec("dask", workers=2))
    assert got == [float(k) for k in range(1, 9)]


def test_an_interrupted_run_resumes_with_only_the_cases_not_done(tmp_path):
    log = tmp_path / "cases.jsonl"
    settings = {"what": "square roots", "n": len(SQUARES)}
    calls: list[float] = []

    def root(x: float) -> float:
        calls.append(x)
        return math.sqrt(x)

    def stop_after_three(k: int, n: int, r: float) -> None:
        if k == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_cases(root, SQUARES, ExecutorSpec("local", workers=1), results=log, settings=settings,
                  progress=stop_after_three)  # fmt: skip
    with log.open("a") as f:
        f.write('{"case": "16.0", "resu')  # the line being written when the power failed
    calls.clear()
    seen: list[int] = []
    got = run_cases(root, SQUARES, ExecutorSpec("local", workers=1), results=log, settings=settings,
                    progress=lambda k, n, r: seen.append(k))  # fmt: skip
    assert got == [float(k) for k in range(1, 9)]
    assert calls == SQUARES[3:] and seen == list(range(1, 9))
    lines = [json.loads(x) for x in log.read_text().splitlines()]
    assert lines[0] == {"settings": settings} and [x["case"] for x in lines[1:]] == [str(x) for x in SQUARES]
    # the same file on a pool of 2 processes: nothing left to run, the same answer
    assert run_cases(math.sqrt, SQUARES, ExecutorSpec("local", workers=2), results=log, settings=settings) == got


def test_a_results_file_of_another_run_is_refused(tmp_path):
    log = tmp_path / "cases.jsonl"
    CaseLog(log, {"seed": 1})
    with pytest.raises(FanoutError, match=r"cases\.jsonl.*'seed': 1.*another --results"):
        run_cases(math.sqrt, SQUARES, results=log, settings={"seed": 2})


def test_bad_executor_settings_are_refused():
    with pytest.raises(FanoutError, match=r"'ray'.*local, dask"):
        ExecutorSpec("ray")  # type: ignore[arg-type]
    with pytest.raises(FanoutError, match=r"tcp://x:8786.*dask executor"):
        ExecutorSpec("local", scheduler="tcp://x:8786")
    with pytest.raises(FanoutError, match="workers 0"):
        ExecutorSpec("local", workers=0)
