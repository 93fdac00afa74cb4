"""Crash-safe session store: SQLite in WAL mode with one transaction per finished point.

Tables: sessions, points, raw (arrays as .npy blobs), events, results, and
schema_version for explicit migrations. Each point and its raw arrays are
committed together with synchronous=FULL, so a point is durable before the
next one starts and a crash (even kill -9) leaves every finished point readable.
"""

from __future__ import annotations

import io
import json
import sqlite3
import threading
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from station.errors import StationFault
from station.session import Measurement, PointRecord, RawStreams, Session, StationInfo

SCHEMA_VERSION = 2  # 2: measurements, measurement_arrays
_SCHEMA = """
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
_RAW_FIELDS = ("grating_t", "grating_z", "pulse_t", "pulse_dir", "reference_t")


class StoreError(StationFault):
    """A store operation that names an unknown session or would duplicate a point."""


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _to_blob(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def _from_blob(b: bytes) -> np.ndarray:
    return np.load(io.BytesIO(b), allow_pickle=False)


class SessionStore:
    """One SQLite file; safe to open from several processes (WAL)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # One connection shared by the engine and control threads: every use holds the lock.
        self._lock = threading.RLock()
        self._db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("PRAGMA foreign_keys=ON")
        with self._tx():
            for stmt in _SCHEMA.strip().split(";"):
                if stmt.strip():
                    self._db.execute(stmt)
            row = self._db.execute("SELECT version FROM schema_version").fetchone()
            if row is None:
                self._db.execute("INSERT INTO schema_version VALUES (?)", (SCHEMA_VERSION,))
            elif row[0] > SCHEMA_VERSION:
                raise StoreError(f"{self.path} has schema version {row[0]}; this software reads up to {SCHEMA_VERSION}")
            elif row[0] < SCHEMA_VERSION:
                # Migrations so far only add tables, which the schema script has just created.
                self._db.execute("UPDATE schema_version SET version = ?", (SCHEMA_VERSION,))

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

    def create_session(
        self,
        station: StationInfo,
        procedure: str,
        *,
        instrument_serial: str = "",
        config: dict | None = None,
        notes: str = "",
        status: str = "running",
    ) -> str:
        uid = datetime.now(UTC).strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:8]
        with self._tx() as db:
            db.execute(
                "INSERT INTO sessions (uid, created_utc, procedure, instrument_serial, status, station_json,"
                " config_json, notes)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    uid,
                    _now(),
                    procedure,
                    instrument_serial,
                    status,
                    json.dumps(asdict(station)),
                    json.dumps(config or {}),
                    notes,
                ),
            )
        return uid

    def add_point(self, uid: str, point: PointRecord, raw: RawStreams | None = None) -> None:
        """Store one finished point and its raw arrays in a single durable transaction."""
        sid = self._session_row(uid)
        try:
            with self._tx() as db:
                cur = db.execute(
                    "INSERT INTO points (session_id, point_id, sequence, start_s, position_deg, freq_hz, kind, pulses,"
                    " Tm_s, t1_s, t2_s, Np, extra_json, recorded_utc)"
                    " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
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
                    ),
                )
                if raw is not None:
                    for name in _RAW_FIELDS:
                        arr = getattr(raw, name)
                        if arr is not None:
                            db.execute("INSERT INTO raw VALUES (?, ?, ?)", (cur.lastrowid, name, _to_blob(arr)))
        except sqlite3.IntegrityError as exc:
            raise StoreError(
                f"session {uid}: point {point.point_id!r} (sequence {point.sequence}) is already stored"
            ) from exc

    def add_measurement(self, uid: str, m: Measurement) -> None:
        """Store one finished measurement and its arrays in a single durable transaction."""
        sid = self._session_row(uid)
        try:
            with self._tx() as db:
                cur = db.execute(
                    "INSERT INTO measurements (session_id, key, kind, values_json, recorded_utc)"
                    " VALUES (?, ?, ?, ?, ?)",
                    (sid, m.key, m.kind, json.dumps(m.values), _now()),
                )
                for name, arr in m.arrays.items():
                    db.execute(
                        "INSERT INTO measurement_arrays VALUES (?, ?, ?)",
                        (cur.lastrowid, name, _to_blob(np.asarray(arr))),
                    )
        except sqlite3.IntegrityError as exc:
            raise StoreError(f"session {uid}: measurement {m.key!r} is already stored") from exc

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
            "SELECT s.uid, s.created_utc, s.procedure, s.instrument_serial, s.status, COUNT(p.id)"
            " FROM sessions s LEFT JOIN points p ON p.session_id = s.id GROUP BY s.id ORDER BY s.id"
        )
        keys = ("uid", "created_utc", "procedure", "instrument_serial", "status", "n_points")
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
        ((station_json, notes, config_json, serial, procedure),) = self._query(
            "SELECT station_json, notes, config_json, instrument_serial, procedure FROM sessions WHERE id = ?", (sid,)
        )
        config = json.loads(config_json)
        rows = self._query(
            "SELECT id, point_id, sequence, start_s, position_deg, freq_hz, kind, pulses, Tm_s, t1_s, t2_s, Np,"
            " extra_json FROM points WHERE session_id = ? ORDER BY sequence",
            (sid,),
        )
        points, raws = [], {}
        for r in rows:
            points.append(
                PointRecord(r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], json.loads(r[12]))
            )
            if with_raw:
                arrays = {
                    n: _from_blob(b) for n, b in self._query("SELECT name, data FROM raw WHERE point_row = ?", (r[0],))
                }
                if arrays:
                    raws[r[1]] = RawStreams(**{n: arrays.get(n) for n in _RAW_FIELDS})
        return Session(
            StationInfo(**json.loads(station_json)),
            points,
            notes=notes,
            raw=raws,
            meta={
                "store_uid": uid,
                "procedure": procedure,
                "params": config.get("params", {}),
                "instrument_serial": serial,
            },
            measurements=self.measurements(uid),  # a measurement's arrays are its data, not raw streams
        )
