"""The read side of the central history: the station store's read functions, answered from PostgreSQL.

`CentralStore` answers sessions, session_config, results, events, measurements and load_session as
`SessionStore` does (StoreError for an unknown uid), so the panel reads either alike; `history` is the
filtered, newest-first listing that the indexes of migration 2 serve without a scan.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from datetime import UTC, date, datetime, time, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa

from station.central.sync import open_central
from station.procedure_names import stored_names
from station.raw_limits import DEFAULT_LIMITS, Budget, RawInputError
from station.safe_arrays import NUMERIC_KINDS, load_npy
from station.safe_files import open_regular
from station.session import Measurement, PointRecord, RawStreams, Session, StationInfo
from station.store import StoreError

ROW_KEYS = ("uid", "created_utc", "procedure", "instrument_serial", "status", "n_points", "n_measurements", "station")
_ROW_SQL = (
    "SELECT uid, created_utc, procedure, instrument_serial, status, n_points, n_measurements, station FROM sessions"
)


@dataclass(frozen=True)
class HistoryQuery:
    """A history filter: part of a serial (any case), procedure, status, station, creation dates (UTC)."""

    serial: str = ""
    procedure: str = ""
    status: str = ""
    station: str = ""
    since: date | None = None
    until: date | None = None


def _iso(t: datetime) -> str:
    return t.astimezone(UTC).isoformat(timespec="milliseconds")


def _like_part(text: str) -> str:
    escaped = text.lower().replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
    return f"%{escaped}%"


class CentralStore:
    """The central history; arrays are read from the lab's array root and checked against their SHA-256."""

    def __init__(self, url: str, arrays: str | Path) -> None:
        self.url = url
        self.engine = open_central(url)
        self.arrays = Path(arrays)
        self.path = url  # where a message says which store it read

    def close(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> CentralStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _rows(self, sql: str, args: dict) -> list[sa.Row]:
        with self.engine.connect() as conn:
            return list(conn.execute(sa.text(sql), args))

    def _sid(self, uid: str) -> int:
        rows = self._rows("SELECT id FROM sessions WHERE uid = :uid", {"uid": uid})
        if not rows:
            raise StoreError(f"no session {uid!r} in the central history")
        return rows[0].id

    @staticmethod
    def _as_dict(r: sa.Row) -> dict:
        d = dict(zip(ROW_KEYS, r, strict=True))
        d["created_utc"] = _iso(d["created_utc"])
        return d

    def history(self, q: HistoryQuery, limit: int) -> list[dict]:
        """Sessions matching `q`, newest first, at most `limit`."""
        where: list[str] = []
        args: dict[str, Any] = {"limit": int(limit)}
        if q.serial:
            where.append("lower(instrument_serial) LIKE :serial")
            args["serial"] = _like_part(q.serial)
        if q.procedure:  # a session stored under a former name is the same procedure's
            names = stored_names(q.procedure)
            where.append("procedure IN (" + ", ".join(f":procedure{i}" for i in range(len(names))) + ")")
            args |= {f"procedure{i}": name for i, name in enumerate(names)}
        for name in ("status", "station"):
            if getattr(q, name):
                where.append(f"{name} = :{name}")
                args[name] = getattr(q, name)
        if q.since is not None:
            where.append("created_utc >= :since")
            args["since"] = datetime.combine(q.since, time(), UTC)
        if q.until is not None:
            where.append("created_utc < :until")
            args["until"] = datetime.combine(q.until + timedelta(days=1), time(), UTC)
        sql = _ROW_SQL + (" WHERE " + " AND ".join(where) if where else "")
        return [self._as_dict(r) for r in self._rows(sql + " ORDER BY created_utc DESC, id DESC LIMIT :limit", args)]

    def row(self, uid: str) -> dict:
        rows = self._rows(_ROW_SQL + " WHERE uid = :uid", {"uid": uid})
        if not rows:
            raise StoreError(f"no session {uid!r} in the central history")
        return self._as_dict(rows[0])

    def sessions(self) -> list[dict]:
        """Every session, oldest first (as SessionStore.sessions, plus the station)."""
        return [self._as_dict(r) for r in self._rows(_ROW_SQL + " ORDER BY created_utc, id", {})]

    def session_config(self, uid: str) -> dict:
        rows = self._rows("SELECT config_json FROM sessions WHERE uid = :uid", {"uid": uid})
        if not rows:
            raise StoreError(f"no session {uid!r} in the central history")
        return json.loads(rows[0].config_json)

    def provenance(self, uid: str) -> dict | None:
        self._sid(uid)
        (r,) = self._rows("SELECT provenance_json FROM sessions WHERE uid = :uid", {"uid": uid})
        return json.loads(r.provenance_json) if r.provenance_json is not None else None

    def results(self, uid: str) -> list[dict]:
        rows = self._rows(
            "SELECT method, created_utc, result_json FROM results WHERE session_id = :sid ORDER BY ordinal",
            {"sid": self._sid(uid)},
        )
        return [{"method": r.method, "created_utc": r.created_utc, "result": json.loads(r.result_json)} for r in rows]

    def events(self, uid: str) -> list[dict]:
        rows = self._rows(
            "SELECT t_utc, level, kind, message FROM events WHERE session_id = :sid ORDER BY ordinal",
            {"sid": self._sid(uid)},
        )
        return [{"t_utc": r.t_utc, "level": r.level, "kind": r.kind, "message": r.message} for r in rows]

    def _array(self, rel: str, sha256: str) -> np.ndarray:
        """An array file of the root, read as data only (station.safe_files, safe_arrays) and checked against its
        SHA-256 on the descriptor it is then read from."""
        path = self.arrays / rel
        if Path(rel).is_absolute() or ".." in Path(rel).parts:
            raise StoreError(f"array file {rel!r} of the central history: not inside the array root {self.arrays}")
        if not os.path.lexists(path):
            raise StoreError(f"array file {path} of the central history is missing")
        try:
            with open_regular(path, str(path)) as f:
                if hashlib.file_digest(f, "sha256").hexdigest() != sha256:
                    raise StoreError(
                        f"array file {path} does not match its SHA-256 {sha256}: it was altered or truncated"
                    )
                f.seek(0)
                return load_npy(f, str(path), Budget(DEFAULT_LIMITS), NUMERIC_KINDS + "U")
        except RawInputError as exc:
            raise StoreError(f"array file of the central history: {exc}") from None

    def _arrays(self, sid: int, owner: str) -> dict[str, dict[str, np.ndarray]]:
        out: dict[str, dict[str, np.ndarray]] = {}
        for r in self._rows(
            "SELECT owner_key, name, path, sha256 FROM arrays WHERE session_id = :sid AND owner = :o ORDER BY name",
            {"sid": sid, "o": owner},
        ):
            out.setdefault(r.owner_key, {})[r.name] = self._array(r.path, r.sha256)
        return out

    def measurements(self, uid: str, *, with_arrays: bool = True) -> list[Measurement]:
        sid = self._sid(uid)
        arrays = self._arrays(sid, "measurement") if with_arrays else {}
        rows = self._rows(
            "SELECT key, kind, values_json FROM measurements WHERE session_id = :sid ORDER BY ordinal", {"sid": sid}
        )
        return [Measurement(r.key, r.kind, json.loads(r.values_json), arrays.get(r.key, {})) for r in rows]

    def load_session(self, uid: str, *, with_raw: bool = True) -> Session:
        sid = self._sid(uid)
        (head,) = self._rows(
            "SELECT station_json, notes, config_json, instrument_serial, procedure, provenance_json"
            " FROM sessions WHERE id = :sid",
            {"sid": sid},
        )
        rows = self._rows(
            'SELECT point_id, sequence, start_s, position_deg, freq_hz, kind, pulses, "Tm_s", t1_s, t2_s, "Np",'
            " extra_json FROM points WHERE session_id = :sid ORDER BY sequence",
            {"sid": sid},
        )
        points = [PointRecord(*r[:11], json.loads(r.extra_json)) for r in rows]  # type: ignore[call-arg]
        raws = {}
        if with_raw:
            for key, arrays in self._arrays(sid, "point").items():
                raws[key] = RawStreams.from_arrays(arrays)
        config = json.loads(head.config_json)
        meta = {
            "store_uid": uid,
            "procedure": config.get("procedure", config.get("imported_procedure")) or head.procedure,
            "params": config.get("params", {}),
            "instrument_serial": head.instrument_serial,
        }
        extra = {}
        fields = Session.__dataclass_fields__
        if head.provenance_json is not None and "provenance" in fields:
            extra["provenance"] = json.loads(head.provenance_json)
        if "record_types" in fields:  # the declarations of issue 14's typed records, kept with each measurement
            extra["record_types"] = self.record_types(uid)
        return Session(
            StationInfo(**json.loads(head.station_json)),
            points,
            notes=head.notes,
            raw=raws,
            meta=meta,
            measurements=self.measurements(uid),
            **extra,
        )

    def record_types(self, uid: str) -> list:
        """The declared record types of the session's measurements, one per kind (station.records)."""
        from station.records import RecordType  # issue 14's typed records

        rows = self._rows(
            "SELECT DISTINCT kind, record_type_json FROM measurements WHERE session_id = :sid AND"
            " record_type_json IS NOT NULL ORDER BY kind",
            {"sid": self._sid(uid)},
        )
        return [RecordType.from_json(json.loads(r.record_type_json), f"{self.url} record type") for r in rows]
