"""Crash-safe session store: SQLite in WAL mode with one transaction per finished point.

Tables: sessions (with provenance and, for an import, its content hash), points, raw (arrays as .npy
blobs), measurements with their arrays and the declared record types of each session (station/records.py),
events, results. The schema version is SQLite's `PRAGMA user_version`, raised by ordered migrations
(`MIGRATIONS`), each in its own transaction; a store newer than the software is refused. The release before
user_version kept its version in a table `schema_version` (2), which is read once and kept in step so that
older software refuses a newer store too. Each point and its raw arrays are committed together with
synchronous=FULL, so a point is durable before the next one starts and a crash (even kill -9) leaves every
finished point readable. An import is one transaction: all of it or none of it. Opening the store removes the
temporary files a killed import or run left in its raw folder (station.leftovers), and logs each one.
"""

from __future__ import annotations

import io
import json
import logging
import re
import shutil
import sqlite3
import threading
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from station.errors import StationFault
from station.leftovers import SUFFIX, remove_leftovers, writing
from station.provenance import local_provenance, software_version, unknown_provenance
from station.rawfile import LazyRaw, write_point_file
from station.records import RecordError, RecordType, declared, infer_record_type
from station.session import Measurement, PointRecord, RawStreams, Session, StationInfo

_V1 = """
CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS sessions (
    id INTEGER PRIMARY KEY,
    uid TEXT NOT NULL UNIQUE,
    created_utc TEXT NOT NULL,
    procedure TEXT NOT NULL,
    instrument_serial TEXT NOT NULL DEFAULT '',
    status TEXT NOT NULL CHECK (status IN ('running', 'finished', 'aborted', 'failed', 'imported')),
    station_json TEXT NOT NULL,
    config_json TEXT NOT NULL DEFAULT '{}',
    notes TEXT NOT NULL DEFAULT ''
);
CREATE TABLE IF NOT EXISTS points (
    id INTEGER PRIMARY KEY,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    point_id TEXT NOT NULL,
    sequence INTEGER NOT NULL,
    start_s REAL NOT NULL,
    position_deg REAL NOT NULL,
    freq_hz REAL NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('static', 'vibration')),
    pulses INTEGER NOT NULL,
    Tm_s REAL NOT NULL,
    t1_s REAL,
    t2_s REAL,
    Np INTEGER,
    extra_json TEXT NOT NULL DEFAULT '{}',
    recorded_utc TEXT NOT NULL,
    UNIQUE (session_id, point_id),
    UNIQUE (session_id, sequence)
);
CREATE TABLE IF NOT EXISTS raw (
    point_row INTEGER NOT NULL REFERENCES points(id),
    name TEXT NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (point_row, name)
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    t_utc TEXT NOT NULL,
    level TEXT NOT NULL,
    kind TEXT NOT NULL,
    message TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS results (
    id INTEGER PRIMARY KEY,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    method TEXT NOT NULL,
    created_utc TEXT NOT NULL,
    result_json TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS points_by_session ON points(session_id, sequence);
"""
_V2 = """
CREATE TABLE IF NOT EXISTS measurements (
    id INTEGER PRIMARY KEY,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    key TEXT NOT NULL,
    kind TEXT NOT NULL,
    values_json TEXT NOT NULL,
    recorded_utc TEXT NOT NULL,
    UNIQUE (session_id, key)
);
CREATE TABLE IF NOT EXISTS measurement_arrays (
    measurement_row INTEGER NOT NULL REFERENCES measurements(id),
    name TEXT NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (measurement_row, name)
);
"""
_V3 = """
ALTER TABLE sessions ADD COLUMN provenance_json TEXT NOT NULL DEFAULT '{}';
ALTER TABLE sessions ADD COLUMN content_hash TEXT;
CREATE UNIQUE INDEX sessions_by_content ON sessions(content_hash) WHERE content_hash IS NOT NULL;
CREATE TABLE record_types (
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    kind TEXT NOT NULL,
    declaration_json TEXT NOT NULL,
    PRIMARY KEY (session_id, kind)
);
"""
_V5 = """
ALTER TABLE points ADD COLUMN raw_file TEXT;
"""
INFERRED = "inferred from records stored before records were declared: units unknown"
IMPORT_MARK = ".import-"  # raw folder: .import-<uid>.tmp, held locked while an import writes <uid>/
_UID = re.compile(r"^[0-9A-Za-z-]{1,64}$")
log = logging.getLogger(__name__)


class StoreError(StationFault):
    """A store operation that names an unknown session, would duplicate a point, or a store this software
    cannot read."""


def _new_uid() -> str:
    return datetime.now(UTC).strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:8]


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _to_blob(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def _from_blob(b: bytes) -> np.ndarray:
    return np.load(io.BytesIO(b), allow_pickle=False)


def _script(sql: str) -> Callable[[sqlite3.Connection], None]:
    def run(db: sqlite3.Connection) -> None:
        for stmt in sql.strip().split(";"):
            if stmt.strip():
                db.execute(stmt)

    return run


def _merged_type(kind: str, records: list[tuple[dict, dict]]) -> RecordType:
    """One declaration for a kind's records stored before records were declared: per field, the widest dtype
    seen (int64 + float64 = float64) and nullable where a record lacks it or holds null."""
    types = [infer_record_type(kind, v, a) for v, a in records]
    fields: dict[str, dict] = {}
    for rt in types:
        for f in rt.fields:
            seen = fields.setdefault(f.name, f.to_json() | {"count": 0})
            seen["count"] += 1
            if f.nullable:
                seen["nullable"] = True
            elif seen["dtype"] == "str" and seen.get("nullable"):
                seen["dtype"], seen["ndim"] = f.dtype, f.ndim
            elif {seen["dtype"], f.dtype} == {"int64", "float64"}:
                seen["dtype"] = "float64"
    doc = {
        "kind": kind,
        "fields": [
            {k: v for k, v in f.items() if k != "count"} | ({"nullable": True} if f["count"] < len(types) else {})
            for f in fields.values()
        ],
        "arrays": [a.to_json() for a in {a.name: a for rt in types for a in rt.arrays}.values()],
        "doc": INFERRED,
    }
    return RecordType.from_json(doc, f"record type {kind}")


def _migrate_v3(db: sqlite3.Connection) -> None:
    """Provenance (unknown but for what the store held: serial, time) and the record types of stored records."""
    _script(_V3)(db)
    for sid, serial, created in db.execute("SELECT id, instrument_serial, created_utc FROM sessions").fetchall():
        prov = unknown_provenance(instrument_serial=serial or None, created_utc=created)
        db.execute("UPDATE sessions SET provenance_json = ? WHERE id = ?", (json.dumps(prov), sid))
    rows = db.execute("SELECT id, session_id, kind, values_json FROM measurements ORDER BY id").fetchall()
    by_kind: dict[tuple[int, str], list[tuple[dict, dict]]] = {}
    for row_id, sid, kind, values_json in rows:
        arrays = {
            n: _from_blob(b)
            for n, b in db.execute("SELECT name, data FROM measurement_arrays WHERE measurement_row = ?", (row_id,))
        }
        by_kind.setdefault((sid, kind), []).append((json.loads(values_json), arrays))
    for (sid, kind), records in by_kind.items():
        db.execute(
            "INSERT INTO record_types VALUES (?, ?, ?)", (sid, kind, json.dumps(_merged_type(kind, records).to_json()))
        )


def _migrate_v4(db: sqlite3.Connection) -> None:
    """Widen the sessions' status CHECK by 'interrupted': a constraint that admits more changes no stored row, so
    the table definition is edited in place (SQLite's documented writable_schema route, schema cookie bumped)."""
    (sql,) = db.execute("SELECT sql FROM sqlite_master WHERE type = 'table' AND name = 'sessions'").fetchone()
    if "'interrupted'" in sql:
        return
    (cookie,) = db.execute("PRAGMA schema_version").fetchone()
    db.execute("PRAGMA writable_schema = ON")
    db.execute(
        "UPDATE sqlite_master SET sql = replace(sql, '''imported'')', '''imported'', ''interrupted'')')"
        " WHERE type = 'table' AND name = 'sessions'"
    )
    db.execute(f"PRAGMA schema_version = {int(cookie) + 1:d}")
    db.execute("PRAGMA writable_schema = OFF")


@dataclass(frozen=True)
class Migration:
    version: int
    name: str
    apply: Callable[[sqlite3.Connection], None]


MIGRATIONS: tuple[Migration, ...] = (
    Migration(1, "sessions, points, raw arrays, events, results", _script(_V1)),
    Migration(2, "measurements and their arrays", _script(_V2)),
    Migration(3, "provenance, content hash of imports, declared record types", _migrate_v3),
    Migration(4, "status 'interrupted' (found running with no live process)", _migrate_v4),
    Migration(5, "raw streams in HDF5 files beside the store (points.raw_file)", _script(_V5)),
)
SCHEMA_VERSION = MIGRATIONS[-1].version


class SessionStore:
    """One SQLite file; safe to open from several processes (WAL)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.raw_dir = self.path.with_name(self.path.name + ".raw")  # the points' raw streams, one HDF5 file each
        # One connection shared by the engine and control threads: every use holds the lock.
        self._lock = threading.RLock()
        self._db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, check_same_thread=False)
        try:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._migrate()
            self._remove_leftovers()
        except BaseException:
            self._db.close()
            raise

    def _remove_leftovers(self) -> None:
        """The temporary files of killed writers in the raw folder, and the raw files of a killed import."""

        def killed_import(marker: Path) -> None:
            uid = marker.name.removeprefix(IMPORT_MARK).removesuffix(SUFFIX)
            ours = marker.parent == self.raw_dir and marker.name.startswith(IMPORT_MARK) and _UID.match(uid)
            if ours and not self._db.execute("SELECT 1 FROM sessions WHERE uid = ?", (uid,)).fetchone():
                shutil.rmtree(self.raw_dir / uid, ignore_errors=True)
                log.warning("%s: removed %s, the raw files of an import that was killed", self.path, uid)

        for path in remove_leftovers(self.raw_dir, killed_import):
            log.warning("%s: removed %s, left by a killed import or run", self.path, path)

    def _version(self) -> int:
        (version,) = self._db.execute("PRAGMA user_version").fetchone()
        if version:
            return int(version)
        legacy = self._db.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'schema_version'")
        if legacy.fetchone() is None:
            return 0
        row = self._db.execute("SELECT version FROM schema_version").fetchone()
        return int(row[0]) if row else 0

    def _migrate(self) -> None:
        """Apply the migrations this store lacks, in order, each in its own transaction."""
        with self._tx():
            version = self._version()
        if version > SCHEMA_VERSION:
            raise StoreError(
                f"{self.path} has schema version {version}, newer than this software reads ({SCHEMA_VERSION}): "
                f"open it with the station software that wrote it, or upgrade (this is {software_version()})"
            )
        for m in MIGRATIONS:
            if m.version <= version:
                continue
            with self._tx() as db:
                if self._version() >= m.version:  # another process migrated meanwhile
                    continue
                m.apply(db)
                db.execute(f"PRAGMA user_version = {m.version:d}")
                db.execute("DELETE FROM schema_version")
                db.execute("INSERT INTO schema_version VALUES (?)", (m.version,))

    @property
    def schema_version(self) -> int:
        with self._lock:
            return self._version()

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> SessionStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")

    def _session_row(self, uid: str) -> int:
        with self._lock:
            row = self._db.execute("SELECT id FROM sessions WHERE uid = ?", (uid,)).fetchone()
        if row is None:
            raise StoreError(f"no session {uid!r} in {self.path}")
        return int(row[0])

    @staticmethod
    def _insert_session(
        db: sqlite3.Connection,
        station: StationInfo,
        procedure: str,
        instrument_serial: str,
        config: dict,
        notes: str,
        status: str,
        provenance: dict,
        content_hash: str | None = None,
        uid: str | None = None,
    ) -> tuple[str, int]:
        uid = uid or _new_uid()
        cur = db.execute(
            "INSERT INTO sessions (uid, created_utc, procedure, instrument_serial, status, station_json,"
            " config_json, notes, provenance_json, content_hash)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                uid,
                _now(),
                procedure,
                instrument_serial,
                status,
                json.dumps(asdict(station)),
                json.dumps(config),
                notes,
                json.dumps(provenance),
                content_hash,
            ),
        )
        assert cur.lastrowid is not None  # an INSERT
        return uid, cur.lastrowid

    def create_session(
        self,
        station: StationInfo,
        procedure: str,
        *,
        instrument_serial: str = "",
        config: dict | None = None,
        notes: str = "",
        status: str = "running",
        provenance: dict | None = None,
    ) -> str:
        """A new session; `provenance` from station.provenance.make_provenance (what the store alone knows
        - software, host, operator, time, serial - when not given)."""
        if provenance is None:
            provenance = local_provenance(instrument_serial=instrument_serial or None)
        serial = instrument_serial or provenance.get("instrument_serial") or ""
        with self._tx() as db:
            uid, _ = self._insert_session(
                db, station, procedure, serial, config or {}, notes, status, provenance
            )  # fmt: skip
        return uid

    def _raw_path(self, uid: str, sequence: int) -> tuple[str, Path]:
        """Where a point's raw streams go: <store>.raw/<uid>/<sequence>.h5 (relative name, path)."""
        rel = f"{uid}/{sequence:06d}.h5"
        return rel, self.raw_dir / rel

    @staticmethod
    def _insert_point(db: sqlite3.Connection, sid: int, point: PointRecord, raw_file: str | None) -> None:
        db.execute(
            "INSERT INTO points (session_id, point_id, sequence, start_s, position_deg, freq_hz, kind, pulses,"
            " Tm_s, t1_s, t2_s, Np, extra_json, recorded_utc, raw_file)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                sid,
                point.point_id,
                point.sequence,
                point.start_s,
                point.position_deg,
                point.freq_hz,
                point.kind,
                point.pulses,
                point.Tm_s,
                point.t1_s,
                point.t2_s,
                point.Np,
                json.dumps(point.extra),
                _now(),
                raw_file,
            ),
        )

    def add_point(self, uid: str, point: PointRecord, raw: RawStreams | None = None) -> None:
        """Store one finished point durably: its raw streams first (an HDF5 file of their own, written, flushed
        and renamed into place), then its row in one transaction. A crash between the two leaves a file no row
        names, which the point's next try replaces."""
        sid = self._session_row(uid)
        taken = self._query(
            "SELECT point_id, sequence FROM points WHERE session_id = ? AND (point_id = ? OR sequence = ?)",
            (sid, point.point_id, point.sequence),
        )
        if taken:
            raise StoreError(f"session {uid}: point {point.point_id!r} (sequence {point.sequence}) is already stored")
        raw_file = None
        if raw is not None:
            raw_file, path = self._raw_path(uid, point.sequence)
            write_point_file(path, raw)
        try:
            with self._tx() as db:
                self._insert_point(db, sid, point, raw_file)
        except sqlite3.IntegrityError as exc:
            raise StoreError(
                f"session {uid}: point {point.point_id!r} (sequence {point.sequence}) is already stored"
            ) from exc

    def _record_type(self, db: sqlite3.Connection, sid: int, kind: str, given: RecordType | None) -> RecordType:
        """The session's declaration of `kind`: stored with its first record, then the one every record uses. A
        session recorded before declarations (an upgraded store) keeps the declaration inferred from its records,
        so that it can be resumed by software that declares the kind; any other difference is refused."""
        row = db.execute("SELECT declaration_json FROM record_types WHERE session_id = ? AND kind = ?", (sid, kind))
        stored = row.fetchone()
        if stored is not None:
            rt = RecordType.from_json(json.loads(stored[0]), f"{self.path} record type")
            if given is not None and given.to_json() != rt.to_json() and rt.doc != INFERRED:
                raise StoreError(
                    f"record type {kind!r}: this software declares it otherwise than the session holds it "
                    f"(stored {rt.to_json()}, declared {given.to_json()})"
                )
            return rt
        if given is None:
            raise StoreError(
                f"measurement kind {kind!r} is not declared: a method declares its record types "
                "(station.records.declare) before it records them"
            )
        db.execute("INSERT INTO record_types VALUES (?, ?, ?)", (sid, kind, json.dumps(given.to_json())))
        return given

    def _insert_measurement(self, db: sqlite3.Connection, sid: int, m: Measurement, rt: RecordType | None) -> None:
        rt = self._record_type(db, sid, m.kind, rt or declared(m.kind))
        try:
            m = m.checked(rt)
        except RecordError as exc:
            raise StoreError(str(exc)) from exc
        cur = db.execute(
            "INSERT INTO measurements (session_id, key, kind, values_json, recorded_utc) VALUES (?, ?, ?, ?, ?)",
            (sid, m.key, m.kind, json.dumps(m.values), _now()),
        )
        for name, arr in m.arrays.items():
            db.execute("INSERT INTO measurement_arrays VALUES (?, ?, ?)", (cur.lastrowid, name, _to_blob(arr)))

    def add_measurement(self, uid: str, m: Measurement, record_type: RecordType | None = None) -> None:
        """Store one finished measurement and its arrays in a single durable transaction, checked against its
        declared record type (station.records)."""
        sid = self._session_row(uid)
        try:
            with self._tx() as db:
                self._insert_measurement(db, sid, m, record_type)
        except sqlite3.IntegrityError as exc:
            raise StoreError(f"session {uid}: measurement {m.key!r} is already stored") from exc

    def import_session(self, session: Session, content_hash: str) -> tuple[str, bool]:
        """Store a whole validated session in one transaction: (uid, True), or (uid of the session already
        imported with the same content hash, False). The uid is the export's (session.json store_uid), else a
        new one; the export's uid held by other content is refused. Nothing is written when any record is
        refused."""
        with self._lock:
            row = self._db.execute("SELECT uid FROM sessions WHERE content_hash = ?", (content_hash,)).fetchone()
        if row is not None:
            return str(row[0]), False
        uid = session.meta.get("store_uid")  # an export's uid is kept: its certificate names it
        if not (isinstance(uid, str) and _UID.match(uid)):
            uid = _new_uid()
        elif self._query("SELECT 1 FROM sessions WHERE uid = ?", (uid,)):
            raise StoreError(f"import refused, nothing stored: session {uid} is already in {self.path} with other "
                             "content (its session.json store_uid names it)")  # fmt: skip
        self.raw_dir.mkdir(parents=True, exist_ok=True)
        with writing(self.raw_dir / f"{IMPORT_MARK}{uid}{SUFFIX}") as marker:  # a killed import's files: leftovers
            try:
                self._import_rows(session, content_hash, uid)
            finally:
                marker.unlink()
        return uid, True

    def _import_rows(self, session: Session, content_hash: str, uid: str) -> None:
        """The raw files, then the rows in one transaction; on any failure the raw files are removed."""
        raw_files: dict[str, str] = {}
        meta = session.meta
        procedure = str(meta.get("procedure") or "imported")
        config = {"imported_procedure": meta.get("procedure"), "params": meta.get("params", {})}
        provenance = session.provenance or unknown_provenance()
        serial = str(meta.get("instrument_serial") or provenance.get("instrument_serial") or "")
        types = {rt.kind: rt for rt in session.record_types}
        try:
            for p in session.points:  # one point's arrays in memory at a time
                if p.point_id in session.raw:
                    raw_files[p.point_id], path = self._raw_path(uid, p.sequence)
                    write_point_file(path, session.raw[p.point_id])
            with self._tx() as db:
                _, sid = self._insert_session(db, session.station, procedure, serial, config, session.notes,
                                              "imported", provenance, content_hash, uid)  # fmt: skip
                for p in session.points:
                    self._insert_point(db, sid, p, raw_files.get(p.point_id))
                for m in session.measurements:
                    self._insert_measurement(db, sid, m, types.get(m.kind))
                for r in session.results:
                    db.execute(
                        "INSERT INTO results (session_id, method, created_utc, result_json) VALUES (?, ?, ?, ?)",
                        (sid, r["method"], r["created_utc"], json.dumps(r["result"])),
                    )
        except sqlite3.IntegrityError as exc:
            shutil.rmtree(self.raw_dir / uid, ignore_errors=True)
            raise StoreError(f"import refused, nothing stored: {exc}") from exc
        except BaseException:
            shutil.rmtree(self.raw_dir / uid, ignore_errors=True)
            raise

    def measurements(self, uid: str, *, with_arrays: bool = True) -> list[Measurement]:
        rows = self._query(
            "SELECT id, key, kind, values_json FROM measurements WHERE session_id = ? ORDER BY id",
            (self._session_row(uid),),
        )
        out = []
        for row_id, key, kind, values_json in rows:
            arrays = {}
            if with_arrays:
                q = "SELECT name, data FROM measurement_arrays WHERE measurement_row = ?"
                arrays = {n: _from_blob(b) for n, b in self._query(q, (row_id,))}
            out.append(Measurement(key, kind, json.loads(values_json), arrays))
        return out

    def record_types(self, uid: str) -> list[RecordType]:
        """The declared record types of the session's measurements (one per kind)."""
        rows = self._query(
            "SELECT declaration_json FROM record_types WHERE session_id = ? ORDER BY kind", (self._session_row(uid),)
        )
        return [RecordType.from_json(json.loads(d), f"{self.path} record type") for (d,) in rows]

    def provenance(self, uid: str) -> dict:
        ((prov,),) = self._query("SELECT provenance_json FROM sessions WHERE id = ?", (self._session_row(uid),))
        return json.loads(prov)

    def add_event(self, uid: str, kind: str, message: str, level: str = "info") -> None:
        sid = self._session_row(uid)
        with self._tx() as db:
            db.execute(
                "INSERT INTO events (session_id, t_utc, level, kind, message) VALUES (?, ?, ?, ?, ?)",
                (sid, _now(), level, kind, message),
            )

    def add_result(self, uid: str, method: str, result: dict) -> None:
        sid = self._session_row(uid)
        with self._tx() as db:
            db.execute(
                "INSERT INTO results (session_id, method, created_utc, result_json) VALUES (?, ?, ?, ?)",
                (sid, method, _now(), json.dumps(result)),
            )

    def set_status(self, uid: str, status: str) -> None:
        sid = self._session_row(uid)
        with self._tx() as db:
            db.execute("UPDATE sessions SET status = ? WHERE id = ?", (status, sid))

    def _query(self, sql: str, args: tuple = ()) -> list[tuple]:
        with self._lock:
            return self._db.execute(sql, args).fetchall()

    def sessions(self) -> list[dict]:
        rows = self._query(
            "SELECT s.uid, s.created_utc, s.procedure, s.instrument_serial, s.status,"
            " (SELECT COUNT(*) FROM points p WHERE p.session_id = s.id),"
            " (SELECT COUNT(*) FROM measurements m WHERE m.session_id = s.id)"
            " FROM sessions s ORDER BY s.id"
        )
        keys = ("uid", "created_utc", "procedure", "instrument_serial", "status", "n_points", "n_measurements")
        return [dict(zip(keys, r, strict=True)) for r in rows]

    def session_config(self, uid: str) -> dict:
        """The procedure, parameters and configuration the session was started with."""
        ((config_json,),) = self._query("SELECT config_json FROM sessions WHERE id = ?", (self._session_row(uid),))
        return json.loads(config_json)

    def results(self, uid: str) -> list[dict]:
        rows = self._query(
            "SELECT method, created_utc, result_json FROM results WHERE session_id = ? ORDER BY id",
            (self._session_row(uid),),
        )
        return [{"method": m, "created_utc": c, "result": json.loads(j)} for m, c, j in rows]

    def events(self, uid: str) -> list[dict]:
        rows = self._query(
            "SELECT t_utc, level, kind, message FROM events WHERE session_id = ? ORDER BY id",
            (self._session_row(uid),),
        )
        return [dict(zip(("t_utc", "level", "kind", "message"), r, strict=True)) for r in rows]

    def load_session(self, uid: str, *, with_raw: bool = True) -> Session:
        sid = self._session_row(uid)
        ((station_json, notes, config_json, serial, procedure, prov_json),) = self._query(
            "SELECT station_json, notes, config_json, instrument_serial, procedure, provenance_json"
            " FROM sessions WHERE id = ?",
            (sid,),
        )
        config = json.loads(config_json)
        rows = self._query(
            "SELECT id, point_id, sequence, start_s, position_deg, freq_hz, kind, pulses, Tm_s, t1_s, t2_s, Np,"
            " extra_json, raw_file FROM points WHERE session_id = ? ORDER BY sequence",
            (sid,),
        )
        points, raws, files = [], {}, {}
        for r in rows:
            points.append(
                PointRecord(r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], json.loads(r[12]))
            )
            if with_raw and r[13]:
                files[r[1]] = (self.raw_dir / r[13], "/")
            elif with_raw:  # a store from before raw files: arrays as blobs
                arrays = {
                    n: _from_blob(b) for n, b in self._query("SELECT name, data FROM raw WHERE point_row = ?", (r[0],))
                }
                if arrays:
                    raws[r[1]] = RawStreams.from_arrays(arrays)
        return Session(
            StationInfo(**json.loads(station_json)),
            points,
            notes=notes,
            raw=LazyRaw(files, raws),  # the HDF5 files are read point by point, when asked
            meta={
                "store_uid": uid,
                "procedure": config.get("procedure", config.get("imported_procedure")) or procedure,
                "params": config.get("params", {}),
                "instrument_serial": serial,
            },
            measurements=self.measurements(uid),  # a measurement's arrays are its data, not raw streams
            provenance=json.loads(prov_json),
            record_types=self.record_types(uid),
            results=self.results(uid),
        )
