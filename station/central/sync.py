"""`station sync`: push a station's finished, aborted, failed and imported sessions to the central history.

Idempotent by session uid and content hash: a session whose catalog hash (head, status, every row; see
content.py) the central database already holds is skipped, so a second sync adds nothing. Each session goes
in one transaction, after its arrays are on disk (content-addressed files written atomically), so an
interrupted sync leaves every session either whole or absent and the next run resumes where it stopped.
A session that only grew since it was pushed (results added after the analysis, an aborted session resumed)
is extended; one whose central copy holds anything the store does not (same uid, different content) is a
conflict: refused, named, and left as it is.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import sqlalchemy as sa

from station.central.content import (
    FINAL_STATUSES,
    SYNCED_STATUSES,
    ArrayFile,
    Row,
    SessionContent,
    read_session,
)
from station.central.migrations import migrate
from station.errors import InputError, StationFault
from station.store import SessionStore

CONNECT_TIMEOUT_S = 10  # a station whose network is down waits this long, then carries on (its store is the journal)
LOG_ORDER = {"points": "sequence", "measurements": "ordinal", "events": "ordinal", "results": "ordinal"}


class CentralError(InputError):
    """A central database URL or array root that cannot be used (the message names it and what is allowed)."""


class SyncConflict(StationFault):
    """The central history holds a session of the same uid with content the store does not have."""


def open_central(url: str) -> sa.Engine:
    """An engine on the central PostgreSQL database; times are read and written in UTC."""
    if not url.startswith(("postgresql://", "postgresql+psycopg://")):
        raise CentralError(f"central database {url!r}: expected a postgresql:// or postgresql+psycopg:// URL")
    if url.startswith("postgresql://"):
        url = "postgresql+psycopg://" + url.removeprefix("postgresql://")
    try:
        return sa.create_engine(
            url, pool_pre_ping=True, connect_args={"options": "-c timezone=UTC", "connect_timeout": CONNECT_TIMEOUT_S}
        )
    except sa.exc.ArgumentError as exc:
        raise CentralError(f"central database {url!r}: {exc}") from None


class ArrayRoot:
    """The lab's directory of array files, named by their SHA-256 (the same array is one file)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise CentralError(f"array root {str(self.path)!r}: not a directory")

    @staticmethod
    def relative(sha256: str) -> str:
        return f"{sha256[:2]}/{sha256[2:4]}/{sha256}.npy"

    def put(self, a: ArrayFile) -> tuple[str, bool]:
        """(path relative to the root, whether it was written): written once, atomically, fsynced."""
        rel = self.relative(a.sha256)
        target = self.path / rel
        if target.is_file() and target.stat().st_size == len(a.data) and ArrayFile.sha256_of_file(target) == a.sha256:
            return rel, False
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=".part-")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(a.data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return rel, True


@dataclass
class SyncReport:
    """What one sync did, session by session."""

    added: list[str] = field(default_factory=list)
    extended: list[str] = field(default_factory=list)
    unchanged: list[str] = field(default_factory=list)
    conflicts: list[str] = field(default_factory=list)  # one message per refused session
    not_yet: list[str] = field(default_factory=list)  # running: pushed once it ends
    files_written: int = 0
    bytes_written: int = 0
    wall_s: float = 0.0

    def summary(self) -> str:
        return (
            f"{len(self.added)} added, {len(self.extended)} extended, {len(self.unchanged)} unchanged, "
            f"{len(self.conflicts)} refused, {len(self.not_yet)} still running; {self.files_written} array "
            f"files ({self.bytes_written / 1e6:.1f} MB) in {self.wall_s:.2f} s"
        )


def _central_logs(conn: sa.Connection, sid: int) -> dict[str, list[str]]:
    return {
        table: list(
            conn.execute(
                sa.text(f"SELECT row_sha256 FROM {table} WHERE session_id = :sid ORDER BY {order}"), {"sid": sid}
            ).scalars()
        )
        for table, order in LOG_ORDER.items()
    }


def extension_start(conn: sa.Connection, central: sa.Row, local: SessionContent) -> dict[str, int]:
    """How many rows of each log the central copy already has, if the store's session extends it; else
    SyncConflict naming what differs."""
    where = f"session {local.uid}: the central database holds a different session of this uid"
    if central.head_sha256 != local.head_sha256:
        raise SyncConflict(
            f"{where} (its uid, time, procedure, serial, station, configuration, notes or "
            f"provenance differ); refused, nothing changed"
        )
    if central.status in FINAL_STATUSES and central.status != local.status:
        raise SyncConflict(f"{where}: central status {central.status!r}, store status {local.status!r}; refused")
    start = {}
    for table, hashes in _central_logs(conn, central.id).items():
        rows: list[Row] = local.logs[table]
        if len(hashes) > len(rows):
            raise SyncConflict(f"{where}: it has {len(hashes)} {table}, the store {len(rows)}; refused")
        for i, h in enumerate(hashes):
            if rows[i].sha256 != h:
                raise SyncConflict(f"{where}: {table} {rows[i].key!r} (#{i}) differs; refused, nothing changed")
        start[table] = len(hashes)
    return start


def _insert(conn: sa.Connection, table: str, rows: list[dict], suffix: str = "") -> sa.CursorResult:
    """INSERT of `rows` (all with the same keys, the table's column names) into `table`."""
    cols = list(rows[0])
    names = ", ".join(f'"{c}"' for c in cols)
    values = ", ".join(f":{c}" for c in cols)
    return conn.execute(sa.text(f"INSERT INTO {table} ({names}) VALUES ({values}){suffix}"), rows)


def _insert_logs(conn: sa.Connection, sid: int, s: SessionContent, start: dict[str, int], paths: dict) -> None:
    """The rows of each log from `start[log]` on, and the arrays of the new points and measurements."""
    new = {table: s.logs[table][start[table] :] for table in LOG_ORDER}
    for table, rows in new.items():
        if rows:
            ordinal: dict[str, int] | None = {} if table == "points" else None
            _insert(conn, table, [
                r.columns | {"session_id": sid, "row_sha256": r.sha256}
                | (ordinal if ordinal is not None else {"ordinal": start[table] + i})
                for i, r in enumerate(rows)
            ])  # fmt: skip
    arrays = [("point", r.key, a) for r in new["points"] for a in r.raw]
    arrays += [("measurement", r.key, a) for r in new["measurements"] for a in r.arrays]
    if arrays:
        _insert(conn, "arrays", [
            {"session_id": sid, "owner": owner, "owner_key": key, "name": a.name, "path": paths[a.sha256],
             "sha256": a.sha256, "n_bytes": a.n_bytes}
            for owner, key, a in arrays
        ])  # fmt: skip


_CENTRAL_ROW = "SELECT id, status, head_sha256, catalog_sha256 FROM sessions WHERE uid = :uid"


def _push(engine: sa.Engine, s: SessionContent) -> str:
    """The session (or what it adds) in one transaction, its array files already written; "added",
    "extended" or "unchanged" (another sync pushed the same content meanwhile)."""
    paths = {a.sha256: ArrayRoot.relative(a.sha256) for r in s.points + s.measurements for a in r.raw + r.arrays}
    state = {"status": s.status, "n_points": s.n_points, "n_measurements": s.n_measurements,
             "catalog_sha256": s.catalog_sha256, "content_sha256": s.content_sha256}  # fmt: skip
    with engine.begin() as conn:
        central = conn.execute(sa.text(_CENTRAL_ROW + " FOR UPDATE"), {"uid": s.uid}).one_or_none()
        if central is None:
            head = s.head | state | {"station": s.station, "head_sha256": s.head_sha256}
            sid = _insert(conn, "sessions", [head], " ON CONFLICT (uid) DO NOTHING RETURNING id").scalar()
            if sid is None:  # another sync of the same store got there first: compare with what it wrote
                raise _RetryError
            _insert_logs(conn, sid, s, dict.fromkeys(LOG_ORDER, 0), paths)
            return "added"
        if central.catalog_sha256 == s.catalog_sha256:
            return "unchanged"
        start = extension_start(conn, central, s)
        _insert_logs(conn, central.id, s, start, paths)
        columns = ", ".join(f"{c} = :{c}" for c in state)
        conn.execute(
            sa.text(f"UPDATE sessions SET {columns}, synced_utc = now() WHERE id = :id"), state | {"id": central.id}
        )
        return "extended"


def _write(root: ArrayRoot, a: ArrayFile, report: SyncReport) -> None:
    written = root.put(a)[1]
    report.files_written += written
    report.bytes_written += a.n_bytes if written else 0


class _RetryError(Exception):
    pass


def sync_store(
    store: SessionStore,
    engine: sa.Engine,
    arrays: str | Path,
    station: str,
    *,
    uids: Iterable[str] | None = None,
    progress: Callable[[str, str], None] | None = None,
) -> SyncReport:
    """Push the store's ended sessions (or those of `uids`) to the central database; what was done.

    `station` names the station in the central history when a session's provenance does not.
    `progress(uid, outcome)` is called once each session is committed (or found unchanged or refused).
    """
    t0 = time.perf_counter()
    migrate(engine)
    root = ArrayRoot(arrays)
    wanted = None if uids is None else set(uids)
    report = SyncReport()
    rows = [r for r in store.sessions() if wanted is None or r["uid"] in wanted]
    with engine.connect() as conn:
        central = {
            r.uid: r
            for r in conn.execute(
                sa.text("SELECT id, uid, status, head_sha256, catalog_sha256 FROM sessions WHERE uid = ANY(:u)"),
                {"u": [r["uid"] for r in rows]},
            )
        }
    for row in rows:
        uid = row["uid"]
        if row["status"] not in SYNCED_STATUSES:
            report.not_yet.append(uid)
            continue
        light = read_session(store, row, station, with_raw=False)
        known = central.get(uid)
        if known is not None and known.catalog_sha256 == light.catalog_sha256:
            outcome = "unchanged"
        else:
            try:
                if known is not None:  # refused before any raw stream is read or written
                    with engine.connect() as conn:
                        extension_start(conn, known, light)
                full = read_session(store, row, station, with_raw=True, sink=lambda a: _write(root, a, report))
                try:
                    outcome = _push(engine, full)
                except _RetryError:
                    outcome = _push(engine, full)
            except SyncConflict as exc:
                report.conflicts.append(str(exc))
                outcome = "refused"
        if outcome != "refused":
            getattr(report, outcome).append(uid)
        if progress is not None:
            progress(uid, outcome)
    report.wall_s = time.perf_counter() - t0
    return report
