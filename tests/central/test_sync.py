"""`station sync` against a real PostgreSQL: content round trip, idempotence, growth, conflicts, resumption."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa

from station.central.content import ArrayFile, read_session
from station.central.migrations import SCHEMA_VERSION, CentralSchemaError, migrate
from station.central.reader import CentralStore
from station.central.server import ServerError, pg_bin_dir
from station.central.sync import ArrayRoot, CentralError, open_central, sync_store
from station.store import SessionStore, StoreError

TABLES = ("sessions", "points", "measurements", "arrays", "events", "results")
STATUSES = ("finished", "aborted", "running", "imported", "finished")


def counts(engine: sa.Engine) -> dict[str, int]:
    with engine.connect() as conn:
        return {t: conn.execute(sa.text(f"SELECT count(*) FROM {t}")).scalar() for t in TABLES}


def assert_same_session(store: SessionStore, central: CentralStore, uid: str) -> None:
    a, b = store.load_session(uid), central.load_session(uid)
    assert b.points == a.points
    assert b.station == a.station and b.notes == a.notes and b.meta == a.meta
    assert getattr(b, "provenance", None) == getattr(a, "provenance", None)
    assert sorted(b.raw) == sorted(a.raw)
    for pid, raw in a.raw.items():
        for name in raw.__dataclass_fields__:
            x, y = getattr(raw, name), getattr(b.raw[pid], name)
            assert (x is None and y is None) or (np.array_equal(x, y) and x.dtype == y.dtype)
    assert [(m.key, m.kind, m.values) for m in b.measurements] == [(m.key, m.kind, m.values) for m in a.measurements]
    for ma, mb in zip(a.measurements, b.measurements, strict=True):
        assert sorted(ma.arrays) == sorted(mb.arrays)
        assert all(np.array_equal(ma.arrays[n], mb.arrays[n]) for n in ma.arrays)
    assert central.events(uid) == store.events(uid)
    ra, rb = store.results(uid), central.results(uid)
    assert [(r["method"], r["created_utc"]) for r in rb] == [(r["method"], r["created_utc"]) for r in ra]
    assert [repr(r["result"]) for r in rb] == [repr(r["result"]) for r in ra]  # NaN survives the trip
    assert central.session_config(uid) == store.session_config(uid)
    row = next(r for r in store.sessions() if r["uid"] == uid)
    assert {k: central.row(uid)[k] for k in ("created_utc", "procedure", "instrument_serial", "status")} == {
        k: row[k] for k in ("created_utc", "procedure", "instrument_serial", "status")
    }


def test_sync_pushes_ended_sessions_whole_and_a_second_sync_adds_nothing(tmp_path, central_url, arrays_dir, fill):
    with SessionStore(tmp_path / "s.sqlite") as store:
        uids = fill(store, STATUSES)
        engine = open_central(central_url)
        report = sync_store(store, engine, arrays_dir, "sim")
        ended = [u for u, s in zip(uids, STATUSES, strict=True) if s != "running"]
        assert sorted(report.added) == sorted(ended) and report.not_yet == [uids[2]]
        # per session 2 raw points x 5 streams + 1 measurement array = 11 arrays; a file per distinct array:
        # grating_t, grating_z, pulse_t differ (6 per session), pulse_dir, reference_t and the stretch are shared
        assert counts(engine)["arrays"] == 4 * 11 and report.files_written == 4 * 6 + 3
        with CentralStore(central_url, arrays_dir) as central:
            for uid in ended:
                assert_same_session(store, central, uid)
            with pytest.raises(StoreError, match=uids[2]):
                central.load_session(uids[2])
            assert {r["station"] for r in central.sessions()} == {"sim"}
        before = counts(engine)
        files = sorted(p.name for p in arrays_dir.rglob("*.npy"))
        again = sync_store(store, engine, arrays_dir, "sim")
        assert again.added == [] and again.extended == [] and sorted(again.unchanged) == sorted(ended)
        assert again.files_written == 0 and counts(engine) == before
        assert sorted(p.name for p in arrays_dir.rglob("*.npy")) == files
        with engine.connect() as conn:
            for path, sha in conn.execute(sa.text("SELECT path, sha256 FROM arrays")):
                assert ArrayFile.sha256_of_file(arrays_dir / path) == sha and Path(path).stem == sha
        engine.dispose()


def test_a_session_that_grew_is_extended_and_a_running_one_is_pushed_once_ended(
    tmp_path, central_url, arrays_dir, fill
):
    with SessionStore(tmp_path / "s.sqlite") as store:
        aborted, running = fill(store, ("aborted", "running"))
        engine = open_central(central_url)
        sync_store(store, engine, arrays_dir, "sim")
        # the aborted session resumed and finished, its analysis stored; the running one ends
        s = store.load_session(aborted, with_raw=False)
        last = s.points[-1]
        from dataclasses import replace

        store.add_point(aborted, replace(last, point_id="P-extra", sequence=last.sequence + 1))
        store.add_result(aborted, "integral", {"kz": 2e-3})
        store.set_status(aborted, "finished")
        store.set_status(running, "aborted")
        report = sync_store(store, engine, arrays_dir, "sim")
        assert report.extended == [aborted] and report.added == [running] and report.conflicts == []
        with CentralStore(central_url, arrays_dir) as central:
            assert_same_session(store, central, aborted)
            assert central.row(aborted)["n_points"] == len(s.points) + 1
        assert sync_store(store, engine, arrays_dir, "sim").unchanged == [aborted, running]
        engine.dispose()


def _tamper(db: Path, sql: str) -> None:
    with sqlite3.connect(db) as conn:
        conn.execute(sql)


def test_same_uid_with_different_content_is_refused_and_left_alone(tmp_path, central_url, arrays_dir, fill, copy):
    with SessionStore(tmp_path / "s.sqlite") as store:
        uid, other = fill(store, ("finished", "finished"))
        engine = open_central(central_url)
        sync_store(store, engine, arrays_dir, "sim")
    before = counts(engine)
    # a copy of the store (an old backup restored on another station) whose sessions differ from what was pushed
    for n, (sql, what) in enumerate([
        (f"UPDATE points SET pulses = pulses + 1 WHERE point_id = 'P002-0deg-v9' AND session_id ="
         f" (SELECT id FROM sessions WHERE uid = '{uid}')", "points 'P002-0deg-v9'"),
        (f"UPDATE sessions SET notes = 'edited' WHERE uid = '{uid}'", "configuration, notes"),
        (f"UPDATE sessions SET status = 'aborted' WHERE uid = '{uid}'", "central status 'finished'"),
    ]):  # fmt: skip
        restored = tmp_path / f"copy{n}.sqlite"
        copy(tmp_path / "s.sqlite", restored)
        _tamper(restored, sql)
        with SessionStore(restored) as changed:
            report = sync_store(changed, engine, arrays_dir, "sim")
        assert report.unchanged == [other] and report.added == [] and report.extended == []
        (message,) = report.conflicts
        assert uid in message and what in message and "refused" in message
        assert counts(engine) == before
    with SessionStore(tmp_path / "s.sqlite") as store, CentralStore(central_url, arrays_dir) as central:
        assert_same_session(store, central, uid)
    engine.dispose()


def test_an_interrupted_sync_resumes_where_it_stopped(tmp_path, central_url, arrays_dir, fill):
    with SessionStore(tmp_path / "s.sqlite") as store:
        uids = fill(store, ("finished",) * 4)
        engine = open_central(central_url)

        def stop_after_two(uid: str, outcome: str) -> None:
            if uid == uids[1]:
                raise KeyboardInterrupt  # Ctrl-C between two sessions

        with pytest.raises(KeyboardInterrupt):
            sync_store(store, engine, arrays_dir, "sim", progress=stop_after_two)
        assert counts(engine)["sessions"] == 2
        # the crash came while the third session's first array file was written: a part of it is on disk
        row = next(r for r in store.sessions() if r["uid"] == uids[2])
        first = read_session(store, row, "sim", with_raw=True).points[0].raw[0]
        cut = arrays_dir / ArrayRoot.relative(first.sha256)
        cut.parent.mkdir(parents=True, exist_ok=True)
        cut.write_bytes(first.data[: len(first.data) // 2])
        report = sync_store(store, engine, arrays_dir, "sim")
        assert report.unchanged == uids[:2] and report.added == uids[2:] and counts(engine)["sessions"] == 4
        assert ArrayFile.sha256_of_file(cut) == first.sha256
        with CentralStore(central_url, arrays_dir) as central:
            for uid in uids:
                assert_same_session(store, central, uid)
        engine.dispose()


def test_migrations_apply_once_and_a_newer_database_is_refused(central_url):
    engine = open_central(central_url)
    assert migrate(engine) == list(range(1, SCHEMA_VERSION + 1))
    assert migrate(engine) == []
    with engine.begin() as conn:
        indexes = set(conn.execute(sa.text("SELECT indexname FROM pg_indexes WHERE tablename = 'sessions'")).scalars())
        conn.execute(sa.text("INSERT INTO schema_migrations (version, name) VALUES (:v, 'from the future')"),
                     {"v": SCHEMA_VERSION + 1})  # fmt: skip
    assert {"sessions_by_date", "sessions_by_station", "sessions_by_serial", "sessions_by_serial_part",
            "sessions_by_procedure", "sessions_by_status"} <= indexes  # fmt: skip
    with pytest.raises(CentralSchemaError, match=f"version {SCHEMA_VERSION + 1}.*upgrade"):
        migrate(engine)
    engine.dispose()


def test_a_url_that_is_not_postgresql_is_refused():
    with pytest.raises(CentralError, match=r"'sqlite:///x\.db'.*postgresql://"):
        open_central("sqlite:///x.db")


def _one_synced_session(tmp_path, central_url, arrays_dir, fill) -> str:
    with SessionStore(tmp_path / "s.sqlite") as store:
        (uid,) = fill(store, ("finished",))
        engine = open_central(central_url)
        sync_store(store, engine, arrays_dir, "sim")
        engine.dispose()
    return uid


def test_an_altered_array_file_is_an_error_naming_it(tmp_path, central_url, arrays_dir, fill):
    uid = _one_synced_session(tmp_path, central_url, arrays_dir, fill)
    victim = sorted(arrays_dir.rglob("*.npy"))[0]
    victim.write_bytes(victim.read_bytes()[:-8])
    with CentralStore(central_url, arrays_dir) as central, pytest.raises(StoreError, match=f"{victim}.*SHA-256"):
        central.load_session(uid)


def test_an_array_file_swapped_for_a_link_or_a_fifo_is_refused_unopened(tmp_path, central_url, arrays_dir, fill):
    """Issue 30: the array root is read as data only; a link (to /dev/zero, which would never end) or a FIFO
    (which would block) in place of an array file is refused before it is opened."""
    uid = _one_synced_session(tmp_path, central_url, arrays_dir, fill)
    victim = sorted(arrays_dir.rglob("*.npy"))[0]
    victim.unlink()
    victim.symlink_to("/dev/zero")
    with CentralStore(central_url, arrays_dir) as central, pytest.raises(StoreError, match="a symbolic link"):
        central.load_session(uid)
    victim.unlink()
    os.mkfifo(victim)
    with CentralStore(central_url, arrays_dir) as central, pytest.raises(StoreError, match="a FIFO"):
        central.load_session(uid)


def test_a_machine_without_postgresql_is_told_how_to_install_it(tmp_path):
    (tmp_path / "15" / "bin").mkdir(parents=True)  # a package half removed: no initdb
    with pytest.raises(ServerError, match=r"no .*/\*/bin/initdb.*apt-get install -y postgresql"):
        pg_bin_dir(tmp_path)
    assert (pg_bin_dir() / "pg_ctl").is_file()  # the server these tests run on


def test_a_sync_killed_mid_way_leaves_whole_sessions_and_the_next_one_completes(tmp_path, central_url, arrays_dir,
                                                                                 fill):  # fmt: skip
    db = tmp_path / "s.sqlite"
    with SessionStore(db) as store:
        uids = fill(store, ("finished",) * 6, n_points=40)
    engine = open_central(central_url)
    migrate(engine)
    cmd = [sys.executable, "-m", "station.cli.cli", "sync", str(db), "--to", central_url, "--arrays", str(arrays_dir)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline and proc.poll() is None and counts(engine)["sessions"] == 0:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)  # kill -9 after the first session is committed (or later)
    proc.wait()
    pushed = counts(engine)
    # polled every 20 ms while one 40-point session takes about 50 ms to push: the kill lands mid-way
    assert 1 <= pushed["sessions"] < 6 and pushed["points"] == 40 * pushed["sessions"]  # each session whole
    with SessionStore(db) as store:
        report = sync_store(store, engine, arrays_dir, "sim")
        assert len(report.unchanged) == pushed["sessions"] and len(report.added) == 6 - pushed["sessions"]
        assert counts(engine)["sessions"] == 6
        with CentralStore(central_url, arrays_dir) as central:
            for uid in uids:
                assert_same_session(store, central, uid)
    engine.dispose()
