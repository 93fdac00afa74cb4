"""Fixtures shared across the suite: the links a device test runs on (tests/links.py); one BLAS thread a process."""

from __future__ import annotations

import os

import pytest
from links import CAN_INTERFACES, TRANSPORTS
from threadpoolctl import threadpool_limits

# One BLAS thread in every process of the suite: the two xdist workers already keep both cores busy, and
# OpenBLAS's idle threads spin-wait on the CPU the other worker needs (tests/methods/test_identify.py,
# test_budget_methods.py, test_uncertainty.py and tests/indep/test_cases.py, `-n 2`: 297 s -> 265 s of CPU).
# The variable reaches every process the tests start (the CLI, analysis children, servers, Dask workers) before
# it loads numpy; the limit covers this one, where a plugin may have loaded it first.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
threadpool_limits(limits=1, user_api="blas")


@pytest.fixture(params=TRANSPORTS)
def transport(request: pytest.FixtureRequest) -> str:
    """The serial link between driver and emulator: a pty or a sim:// line."""
    return str(request.param)


@pytest.fixture(params=CAN_INTERFACES)
def interface(request: pytest.FixtureRequest) -> str:
    """The python-can interface of the servo's bus: `virtual` or `station_sim`."""
    return str(request.param)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The modules with a `slow` test first, each kept whole (its module fixtures set up once), the rest in their
    order: under xdist the long tests then run while the short ones fill in around them, instead of one of them
    running alone at the end (the same order in every worker, as xdist requires)."""
    slow = {item.module for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.module not in slow)
