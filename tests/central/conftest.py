"""A real PostgreSQL server (Debian's package, a throwaway cluster on a unix socket) and a real
dask.distributed LocalCluster for the central-history and fan-out tests; nothing is mocked.

PostgreSQL missing is a failure that says how to install it, never a skip.
"""

from __future__ import annotations

import itertools
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa

from station.central.server import ServerError, ThrowawayServer
from station.session import Measurement, RawStreams
from station.store import SessionStore
from station.twin.config import default_twin
from station.twin.plan import seed000_plan
from station.twin.session_sim import simulate_session

_names = itertools.count()


@pytest.fixture(scope="session")
def pg_server() -> Iterator[ThrowawayServer]:
    try:
        server = ThrowawayServer(database="postgres_tests").start()
    except ServerError as exc:
        pytest.fail(f"the central-history tests need a PostgreSQL server: {exc}", pytrace=False)
    try:
        yield server
    finally:
        server.stop()


def new_database(pg_server: ThrowawayServer) -> str:
    """A fresh, empty database on the test server (its SQLAlchemy URL)."""
    name = f"central_{next(_names)}"
    admin = sa.create_engine(pg_server.url, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(sa.text(f"CREATE DATABASE {name}"))
    admin.dispose()
    return pg_server.url.replace(f"/{pg_server.database}?", f"/{name}?")


@pytest.fixture
def central_url(pg_server: ThrowawayServer) -> str:
    return new_database(pg_server)


@pytest.fixture(scope="session")
def database(pg_server: ThrowawayServer):
    """new_database() for fixtures of a wider scope than one test."""
    return lambda: new_database(pg_server)


@pytest.fixture(scope="session")
def dask_scheduler() -> Iterator[str]:
    """Address of a running LocalCluster of 2 single-threaded worker processes (an "existing cluster")."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        yield cluster.scheduler_address


def small_raw(seed: int) -> RawStreams:
    """Raw streams of a few hundred samples (a real window's are tens of MB)."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, 1.0, 200))
    return RawStreams(t, 0.03 * np.sin(2 * np.pi * 8 * t), np.sort(rng.uniform(0.0, 1.0, 50)),
                      np.ones(50, dtype=np.int8), np.array([0.125, 0.25]))  # fmt: skip


def add_measurement(store: SessionStore, uid: str, m: Measurement) -> None:
    """Store a measurement with its record type declared when the store keeps typed records (issue 14)."""
    try:
        from station.records import infer_record_type
    except ImportError:  # a store without typed records
        store.add_measurement(uid, m)
        return
    store.add_measurement(uid, m, infer_record_type(m.kind, m.values, m.arrays))


def fill_store(
    store: SessionStore, statuses: tuple[str, ...], *, serial: str = "PIGA-{k}", n_points: int = 4, first: int = 0
) -> list[str]:
    """One seed-000 session (first `n_points` points of the twin) per status, with raw streams on two points,
    a measurement with an array, events and a result; their uids."""
    uids = []
    for k, status in enumerate(statuses, start=first):
        s = simulate_session(seed000_plan()[:n_points], default_twin(), seed=k)
        uid = store.create_session(s.station, "integral_precession", instrument_serial=serial.format(k=k),
                                   config={"procedure": "integral_precession", "params": {"k": k}})  # fmt: skip
        for i, p in enumerate(s.points):
            store.add_point(uid, p, small_raw(10 * k + i) if i < 2 else None)
        add_measurement(store, uid, Measurement(f"stretch-{k}", "grating_stretch", {"freq_hz": 8.0, "n": 3},
                                                {"z_m": np.linspace(0.0, 0.03, 7)}))  # fmt: skip
        store.add_event(uid, "start", f"session {k}")
        store.add_event(uid, "end", status, "warning" if status != "finished" else "info")
        if status == "finished":
            store.add_result(uid, "integral", {"kz": 1e-3 * (k + 1), "sigma": [1.0, float("nan")]})
        store.set_status(uid, status)
        uids.append(uid)
    return uids


@pytest.fixture
def arrays_dir(tmp_path: Path) -> Path:
    return tmp_path / "arrays"


@pytest.fixture(scope="session")
def fill():
    """fill_store(store, statuses, ...) for the tests (conftest functions are not importable)."""
    return fill_store


@pytest.fixture(scope="session")
def measure():
    return add_measurement


def copy_store(src: Path, dst: Path) -> None:
    """A copy of a store: its SQLite file and, when the store keeps raw streams beside it, their files."""
    shutil.copy(src, dst)
    raw = src.with_name(src.name + ".raw")
    if raw.is_dir():
        shutil.copytree(raw, dst.with_name(dst.name + ".raw"))


@pytest.fixture(scope="session")
def copy():
    return copy_store
