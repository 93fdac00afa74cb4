"""Fan a list of independent cases out to worker processes, locally or on a dask.distributed cluster.

Every case's result is appended to a JSON-lines file as soon as it finishes (one line, flushed and fsynced),
so an interrupted run loses at most the cases under way; run again with the same file and settings, it
resumes with the cases not yet done. The file's first line holds the run's settings: a resume with other
settings is refused rather than mixing two runs. Results come back in the order of the cases whatever the
executor, so a run scored on one executor scores the same on another with the same seeds.

Every case runs with one BLAS thread (threadpoolctl), as dask's workers do by default: the summation order
of a multi-threaded BLAS depends on the threads it gets, and a verdict near a threshold could follow it.

Executors: `local`, a pool of forked processes on this machine (one in-process loop for one worker);
`dask`, the workers of an existing dask.distributed scheduler (`scheduler`, e.g. tcp://head:8786) or,
without one, of a LocalCluster started for the run (one single-threaded worker process per core asked).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import json
import os
from collections.abc import Callable, Hashable, Iterator, Sequence
from dataclasses import asdict, dataclass, is_dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Literal

from threadpoolctl import threadpool_limits

from station.errors import InputError
from station.extras import needs_extra
from station.jsonsafe import json_safe

EXECUTORS = ("local", "dask")


class FanoutError(InputError):
    """A bad executor setting, or a results file that belongs to another run."""


@dataclass(frozen=True)
class ExecutorSpec:
    """Where the cases run: `kind` local|dask, dask's `scheduler` address (None: a LocalCluster), `workers`."""

    kind: Literal["local", "dask"] = "local"
    scheduler: str | None = None
    workers: int | None = None  # None: every core (local, LocalCluster); the cluster's own for a scheduler

    def __post_init__(self) -> None:
        if self.kind not in EXECUTORS:
            raise FanoutError(f"executor {self.kind!r}: expected one of {', '.join(EXECUTORS)}")
        if self.scheduler is not None and self.kind != "dask":
            raise FanoutError(f"scheduler {self.scheduler!r} is for the dask executor, not {self.kind!r}")
        if self.workers is not None and self.workers < 1:
            raise FanoutError(f"workers {self.workers}: expected at least 1")

    @property
    def n_workers(self) -> int:
        return self.workers or os.cpu_count() or 1


def add_executor_options(p: argparse.ArgumentParser, *, workers: bool = True) -> None:
    """--executor, --scheduler, --results (and --workers) on a command that fans cases out."""
    p.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="local: processes on this machine; dask: a dask.distributed cluster (default: local)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="address of a running dask scheduler (tcp://host:8786); without it dask starts a LocalCluster",
    )
    p.add_argument(
        "--results",
        metavar="CASES.jsonl",
        help="append each case's result here as it finishes; an existing file is resumed",
    )
    if workers:
        p.add_argument("--workers", type=int, default=None, help="worker processes (default: every core)")


def spec_from_args(args: argparse.Namespace) -> ExecutorSpec:
    if args.scheduler and args.executor != "dask":
        raise FanoutError(f"--scheduler {args.scheduler}: only with --executor dask")
    return ExecutorSpec(args.executor, args.scheduler, getattr(args, "workers", None))


class CaseLog:
    """The JSON-lines file of a run: a settings line, then one {"case": key, "result": ...} line per case."""

    def __init__(self, path: str | Path, settings: dict) -> None:
        self.path = Path(path)
        self.settings = json_safe(settings)
        self.done: dict[str, Any] = {}
        if self.path.exists() and self.path.stat().st_size:
            self._read()
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._append({"settings": self.settings})

    def _read(self) -> None:
        data = self.path.read_bytes()
        complete = data[: data.rfind(b"\n") + 1]  # a line cut by an interruption is dropped, and rewritten
        if len(complete) != len(data):
            with self.path.open("r+b") as f:
                f.truncate(len(complete))
        lines = complete.decode().splitlines()
        if not lines:
            self._append({"settings": self.settings})
            return
        head = json.loads(lines[0])
        if head.get("settings") != self.settings:
            raise FanoutError(
                f"{self.path}: holds a run with settings {head.get('settings')}, not {self.settings}: "
                "give another --results file to start a new run"
            )
        for n, line in enumerate(lines[1:], start=2):
            doc = json.loads(line)
            if set(doc) != {"case", "result"}:
                raise FanoutError(f"{self.path} line {n}: expected an object with 'case' and 'result'")
            self.done[doc["case"]] = doc["result"]

    def _append(self, doc: dict) -> None:
        with self.path.open("a") as f:
            f.write(json.dumps(doc, allow_nan=False, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def record(self, key: str, result: Any) -> None:
        self._append({"case": key, "result": result})
        self.done[key] = result


def run_pinned(fn: Callable[[Any], Any], case: Any) -> Any:
    """fn(case) with one BLAS thread: the same floating-point sums on every executor."""
    with threadpool_limits(limits=1):
        return fn(case)


def case_key(case: Any) -> str:
    """A case's key in the results file: its JSON (a dataclass by its fields)."""
    doc = asdict(case) if is_dataclass(case) and not isinstance(case, type) else case
    return json.dumps(doc, sort_keys=True, default=str)


@contextlib.contextmanager
def open_executor(spec: ExecutorSpec) -> Iterator[cf.Executor]:
    """A concurrent.futures executor for `spec` (dask's through Client.get_executor), shut down on exit."""
    if spec.kind == "local":
        with cf.ProcessPoolExecutor(spec.n_workers, mp_context=get_context("fork")) as ex:
            yield ex
        return
    with needs_extra("the dask executor"):
        from distributed import Client, LocalCluster

    with contextlib.ExitStack() as stack:
        if spec.scheduler:
            client = stack.enter_context(Client(spec.scheduler, timeout="30s"))
        else:
            cluster = stack.enter_context(
                LocalCluster(n_workers=spec.n_workers, threads_per_worker=1, processes=True, dashboard_address=":0")
            )
            client = stack.enter_context(Client(cluster))
        yield client.get_executor(pure=False)


def run_cases(
    fn: Callable[[Any], Any],
    cases: Sequence[Any],
    spec: ExecutorSpec = ExecutorSpec(),
    *,
    results: str | Path | None = None,
    settings: dict | None = None,
    key: Callable[[Any], Hashable] = case_key,
    progress: Callable[[int, int, Any], None] | None = None,
) -> list[Any]:
    """fn(case) for every case, in the cases' order; each result logged to `results` as it finishes.

    With `results` naming a file of an earlier run with the same `settings`, the cases it holds are not run
    again. `progress(k, n, result)` after each case (done ones first).
    """
    keys = [str(key(c)) for c in cases]
    if len(set(keys)) != len(keys):
        raise FanoutError("two cases have the same key: their results could not be told apart")
    log = CaseLog(results, settings or {}) if results is not None else None
    out: dict[str, Any] = {k: log.done[k] for k in keys if log is not None and k in log.done}
    todo = [(k, c) for k, c in zip(keys, cases, strict=True) if k not in out]
    n = len(cases)
    for i, k in enumerate(out, start=1):
        if progress:
            progress(i, n, out[k])

    def finished(k: str, r: Any) -> None:
        r = json_safe(r)  # what a resumed run reads back: the same in every run
        if log is not None:
            log.record(k, r)
        out[k] = r
        if progress:
            progress(len(out), n, r)

    if spec.kind == "local" and (spec.n_workers == 1 or len(todo) <= 1):
        for k, c in todo:
            finished(k, run_pinned(fn, c))
    elif todo:
        with open_executor(spec) as ex:
            futures = {ex.submit(run_pinned, fn, c): k for k, c in todo}
            try:
                for f in cf.as_completed(futures):
                    finished(futures[f], f.result())
            except BaseException:  # Ctrl-C or a failed case: the cases not started are not run
                for f in futures:
                    f.cancel()
                raise
    return [out[k] for k in keys]
