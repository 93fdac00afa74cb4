"""Other work on the machine, for tests that must not depend on it: processes that spin until told to stop."""

from __future__ import annotations

import multiprocessing
from collections.abc import Iterator
from contextlib import contextmanager
from multiprocessing.synchronize import Event as MpEvent


def _spin(stop: MpEvent) -> None:
    while not stop.is_set():
        pass


@contextmanager
def busy_loops(n: int = 2) -> Iterator[None]:
    """n processes that keep a core each busy for the block (two: a 2-core machine fully loaded)."""
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=_spin, args=(stop,), daemon=True) for _ in range(n)]
    for h in hogs:
        h.start()
    try:
        yield
    finally:
        stop.set()
        for h in hogs:
            h.join()
