"""The central calibration history's schema, as plain ordered SQL migrations tracked in `schema_migrations`.

The logical tables are the station store's (station/store.py: sessions, points, measurements, events,
results, raw and measurement arrays), keyed for a lab of many stations: every session carries the station
that made it, its content hash (for an idempotent sync) and its provenance when the store records one;
every row of a session's append-only logs (points, measurements, events, results) carries its own hash, so
that a sync can tell a session that only grew (results added after it was first pushed) from one whose
content differs. Arrays are files (`arrays.path`, relative to the lab's array root) with a SHA-256.

Migrations run in one transaction under an advisory lock, so stations that start together do not race;
a database newer than this software is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import sqlalchemy as sa

from station.errors import StationFault

_LOCK_KEY = 0x50494741  # "PIGA": the advisory lock that serialises migrations


class CentralSchemaError(StationFault):
    """The central database's schema is newer than this software, or a migration failed."""


@dataclass(frozen=True)
class Migration:
    version: int
    name: str
    sql: str


MIGRATIONS: tuple[Migration, ...] = (
    Migration(
        1,
        "the station store's tables, keyed by station and session uid",
        """
CREATE TABLE sessions (
    id BIGSERIAL PRIMARY KEY,
    uid TEXT NOT NULL UNIQUE,
    station TEXT NOT NULL,
    created_utc TIMESTAMPTZ NOT NULL,
    procedure TEXT NOT NULL,
    instrument_serial TEXT NOT NULL DEFAULT '',
    status TEXT NOT NULL,  -- the store's statuses (running, finished, aborted, failed, interrupted, imported)
    station_json TEXT NOT NULL,
    config_json TEXT NOT NULL DEFAULT '{}',
    notes TEXT NOT NULL DEFAULT '',
    provenance_json TEXT,
    n_points INTEGER NOT NULL,
    n_measurements INTEGER NOT NULL,
    head_sha256 TEXT NOT NULL,
    catalog_sha256 TEXT NOT NULL,
    content_sha256 TEXT NOT NULL,
    synced_utc TIMESTAMPTZ NOT NULL DEFAULT now()
);
CREATE TABLE points (
    id BIGSERIAL PRIMARY KEY,
    session_id BIGINT NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    point_id TEXT NOT NULL,
    sequence INTEGER NOT NULL,
    start_s DOUBLE PRECISION NOT NULL,
    position_deg DOUBLE PRECISION NOT NULL,
    freq_hz DOUBLE PRECISION NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('static', 'vibration')),
    pulses BIGINT NOT NULL,
    "Tm_s" DOUBLE PRECISION NOT NULL,
    t1_s DOUBLE PRECISION,
    t2_s DOUBLE PRECISION,
    "Np" BIGINT,
    extra_json TEXT NOT NULL DEFAULT '{}',
    row_sha256 TEXT NOT NULL,
    UNIQUE (session_id, point_id),
    UNIQUE (session_id, sequence)
);
CREATE TABLE measurements (
    id BIGSERIAL PRIMARY KEY,
    session_id BIGINT NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    ordinal INTEGER NOT NULL,
    key TEXT NOT NULL,
    kind TEXT NOT NULL,
    values_json TEXT NOT NULL,
    record_type_json TEXT,
    row_sha256 TEXT NOT NULL,
    UNIQUE (session_id, key),
    UNIQUE (session_id, ordinal)
);
CREATE TABLE arrays (
    id BIGSERIAL PRIMARY KEY,
    session_id BIGINT NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    owner TEXT NOT NULL CHECK (owner IN ('point', 'measurement')),
    owner_key TEXT NOT NULL,
    name TEXT NOT NULL,
    path TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    n_bytes BIGINT NOT NULL,
    UNIQUE (session_id, owner, owner_key, name)
);
CREATE TABLE events (
    id BIGSERIAL PRIMARY KEY,
    session_id BIGINT NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    ordinal INTEGER NOT NULL,
    t_utc TEXT NOT NULL,
    level TEXT NOT NULL,
    kind TEXT NOT NULL,
    message TEXT NOT NULL,
    row_sha256 TEXT NOT NULL,
    UNIQUE (session_id, ordinal)
);
CREATE TABLE results (
    id BIGSERIAL PRIMARY KEY,
    session_id BIGINT NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    ordinal INTEGER NOT NULL,
    method TEXT NOT NULL,
    created_utc TEXT NOT NULL,
    result_json TEXT NOT NULL,
    row_sha256 TEXT NOT NULL,
    UNIQUE (session_id, ordinal)
);
""",
    ),
    Migration(
        2,
        "indexes of the history queries: newest first, by station, serial, procedure, status",
        """
CREATE EXTENSION IF NOT EXISTS pg_trgm;
CREATE INDEX sessions_by_date ON sessions (created_utc DESC, id DESC);
CREATE INDEX sessions_by_station ON sessions (station, created_utc DESC);
CREATE INDEX sessions_by_serial ON sessions (instrument_serial, created_utc DESC);
CREATE INDEX sessions_by_serial_part ON sessions USING gin (lower(instrument_serial) gin_trgm_ops);
CREATE INDEX sessions_by_procedure ON sessions (procedure, created_utc DESC);
CREATE INDEX sessions_by_status ON sessions (status, created_utc DESC);
CREATE INDEX arrays_by_session ON arrays (session_id);
CREATE INDEX events_by_session ON events (session_id, ordinal);
CREATE INDEX results_by_session ON results (session_id, ordinal);
""",
    ),
)
SCHEMA_VERSION = MIGRATIONS[-1].version

_TRACKING = """
CREATE TABLE IF NOT EXISTS schema_migrations (
    version INTEGER PRIMARY KEY,
    name TEXT NOT NULL,
    applied_utc TIMESTAMPTZ NOT NULL DEFAULT now()
)"""


def applied_versions(conn: sa.Connection) -> list[int]:
    """Versions already applied, in order (empty for a new database)."""
    if not conn.execute(sa.text("SELECT to_regclass('schema_migrations')")).scalar():
        return []
    return list(conn.execute(sa.text("SELECT version FROM schema_migrations ORDER BY version")).scalars())


def migrate(engine: sa.Engine) -> list[int]:
    """Apply the migrations the database lacks, in order, in one transaction; the versions applied."""
    with engine.begin() as conn:
        conn.execute(sa.text("SELECT pg_advisory_xact_lock(:k)"), {"k": _LOCK_KEY})
        conn.execute(sa.text(_TRACKING))
        done = applied_versions(conn)
        if done and done[-1] > SCHEMA_VERSION:
            raise CentralSchemaError(
                f"{engine.url.render_as_string(hide_password=True)}: central schema version {done[-1]}; "
                f"this software knows migrations up to {SCHEMA_VERSION}: upgrade the station software"
            )
        applied = []
        for m in MIGRATIONS:
            if m.version in done:
                continue
            for stmt in m.sql.strip().split(";"):
                if stmt.strip():
                    conn.execute(sa.text(stmt))
            conn.execute(
                sa.text("INSERT INTO schema_migrations (version, name) VALUES (:v, :n)"), {"v": m.version, "n": m.name}
            )
            applied.append(m.version)
    return applied
