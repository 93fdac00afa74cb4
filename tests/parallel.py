"""The Monte Carlo loops of the statistical tests on every core: the project's own fan-out (station.fanout).

`map_seeds(fn, seeds)` is `[fn(s) for s in seeds]`, the cases run on the local executor (forked processes,
one per core) and the results returned in the seeds' order, so a test reads them as it read its serial loop.
Every case runs with one BLAS thread (station.fanout.run_pinned), on one core as on many: the same sums
whatever the machine. `fn` must pickle (a module-level function, or a functools.partial of one); what it
needs beyond its seed and arguments it reads from module globals, which the forked workers inherit.

Before moving a loop here, compare its results with the serial loop's: they must be bit-identical. They are for
seed 000's simulate_session + identify + budget (tests/methods/test_identify.py, test_uncertainty.py); seed 001's
tumble analysis is not (one BLAS thread instead of two moves the last bit of some fits), so its loops stay serial.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from station.fanout import ExecutorSpec, open_executor, run_pinned


def map_seeds(fn: Callable[[Any], Any], seeds: Iterable[Any]) -> list[Any]:
    """fn(seed) for every seed, on every core; the results in the seeds' order."""
    seeds = list(seeds)
    spec = ExecutorSpec("local")
    if spec.n_workers == 1 or len(seeds) <= 1:
        return [run_pinned(fn, s) for s in seeds]
    with open_executor(spec) as ex:
        return list(ex.map(run_pinned, [fn] * len(seeds), seeds))
