"""One stored session as the central history holds it: rows in a canonical form, each with its SHA-256.

Read through the station store's public functions only (sessions, session_config, load_session, events,
results), so that whatever the store keeps internally, the central copy is what the store answers.
A session's head (uid, time, procedure, serial, station, configuration, notes, provenance) never changes;
its points, measurements, events and results are append-only logs, so a later copy of a session either
extends an earlier one (results added after the analysis, an aborted session resumed) or conflicts with it.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from station.session import RAW_FIELDS, Session
from station.store import SessionStore

SYNCED_STATUSES = ("finished", "aborted", "failed", "interrupted", "imported")  # not while running
FINAL_STATUSES = ("finished", "imported")  # a central copy in one of these cannot grow any more


def canonical(obj: Any) -> str:
    """JSON text that is the same for equal content (sorted keys, no spaces; NaN kept as the store keeps it)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class ArrayFile:
    """One array as the bytes of an .npy file and their SHA-256 (the file's name in the array root); once
    written, `released()` keeps the checksum and size without the bytes."""

    name: str
    data: bytes
    sha256: str
    n_bytes: int = -1  # len(data), kept when the data is released

    def __post_init__(self) -> None:
        if self.n_bytes < 0:
            object.__setattr__(self, "n_bytes", len(self.data))

    def released(self) -> ArrayFile:
        return ArrayFile(self.name, b"", self.sha256, self.n_bytes)

    @classmethod
    def of(cls, name: str, a: np.ndarray) -> ArrayFile:
        buf = io.BytesIO()
        np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
        data = buf.getvalue()
        return cls(name, data, hashlib.sha256(data).hexdigest())

    @staticmethod
    def sha256_of_file(path: Path) -> str:
        with path.open("rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()


@dataclass
class Row:
    """One row of a session's log: its columns, its arrays, and a hash over both."""

    key: str  # point_id, measurement key, or the ordinal of an event or result
    columns: dict[str, Any]
    arrays: list[ArrayFile] = field(default_factory=list)  # a measurement's arrays: its data
    raw: list[ArrayFile] = field(default_factory=list)  # a point's raw streams, when loaded

    @property
    def sha256(self) -> str:
        """Hash of the columns and arrays, without the raw streams (the store never rewrites a point's raw)."""
        return sha256_text(canonical([self.columns, sorted((a.name, a.sha256) for a in self.arrays)]))

    @property
    def full_sha256(self) -> str:
        return sha256_text(canonical([self.sha256, sorted((a.name, a.sha256) for a in self.raw)]))


@dataclass
class SessionContent:
    """Everything the central history keeps of one session."""

    uid: str
    station: str
    head: dict[str, Any]
    status: str
    points: list[Row]
    measurements: list[Row]
    events: list[Row]
    results: list[Row]
    with_raw: bool

    @property
    def head_sha256(self) -> str:
        return sha256_text(canonical(self.head))

    @property
    def logs(self) -> dict[str, list[Row]]:
        return {
            "points": self.points,
            "measurements": self.measurements,
            "events": self.events,
            "results": self.results,
        }

    @property
    def catalog_sha256(self) -> str:
        """Hash of the head, the status and every row but the points' raw streams: what decides a re-sync."""
        return sha256_text(
            canonical([self.head_sha256, self.status, [[r.sha256 for r in v] for v in self.logs.values()]])
        )

    @property
    def content_sha256(self) -> str:
        """Hash of everything, raw streams included (loaded with_raw)."""
        if not self.with_raw:
            raise ValueError(f"session {self.uid}: the content hash needs the raw streams (read with_raw=True)")
        return sha256_text(canonical([self.catalog_sha256, [r.full_sha256 for r in self.points]]))

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def n_measurements(self) -> int:
        return len(self.measurements)


def provenance_of(store: SessionStore, session: Session) -> dict | None:
    """The session's provenance record if the store keeps one (issue 14), else None."""
    prov = getattr(session, "provenance", None) or session.meta.get("provenance")
    if not prov and callable(getattr(store, "provenance", None)):
        prov = store.provenance(session.meta["store_uid"])
    return prov or None


def record_types_of(session: Session) -> dict[str, dict]:
    """The declaration of each measurement kind (station.records, issue 14) as JSON, by kind; {} before it."""
    return {rt.kind: rt.to_json() for rt in getattr(session, "record_types", [])}


def read_session(
    store: SessionStore, row: dict, station: str, *, with_raw: bool, sink: Callable[[ArrayFile], None] | None = None
) -> SessionContent:
    """The central form of the store's session `row` (an element of store.sessions()).

    With `sink`, every array is handed to it (to be written) and kept as its checksum and size only: the
    store reads raw streams point by point, so one point's arrays are in memory at a time."""

    def taken(a: ArrayFile) -> ArrayFile:
        if sink is None:
            return a
        sink(a)
        return a.released()

    uid = row["uid"]
    session = store.load_session(uid, with_raw=with_raw)
    prov = provenance_of(store, session)
    head = {
        "uid": uid,
        "created_utc": row["created_utc"],
        "procedure": row["procedure"],
        "instrument_serial": row["instrument_serial"],
        "station_json": canonical(asdict(session.station)),
        "config_json": canonical(store.session_config(uid)),
        "notes": session.notes,
        "provenance_json": canonical(prov) if prov is not None else None,
    }
    points = []
    for p in session.points:
        cols = asdict(p)
        cols["extra_json"] = canonical(cols.pop("extra"))
        raw = session.raw.get(p.point_id) if with_raw else None
        arrays = [
            taken(ArrayFile.of(n, a)) for n in RAW_FIELDS if raw is not None and (a := getattr(raw, n)) is not None
        ]
        points.append(Row(p.point_id, cols, raw=arrays))
    types = record_types_of(session)
    measurements = [
        Row(
            m.key,
            {
                "key": m.key,
                "kind": m.kind,
                "values_json": canonical(m.values),
                "record_type_json": canonical(types[m.kind]) if m.kind in types else None,
            },
            [taken(ArrayFile.of(n, np.asarray(a))) for n, a in sorted(m.arrays.items())],
        )
        for m in session.measurements
    ]
    events = [Row(str(i), e) for i, e in enumerate(store.events(uid))]
    results = [
        Row(str(i), {"method": r["method"], "created_utc": r["created_utc"], "result_json": canonical(r["result"])})
        for i, r in enumerate(store.results(uid))
    ]
    name = (prov or {}).get("station_id") or station
    return SessionContent(uid, name, head, row["status"], points, measurements, events, results, with_raw)
