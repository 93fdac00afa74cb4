"""Session history across the stations' stores: listing with filters, a session's record, residuals and report.

The stores are the stations' own SQLite files, read while the stations write
them (WAL). Several stations may share one store; a session is found by its
uid, which is unique across stores. With a central history configured
(`[central]` in the panel file, issue 16), every page reads the lab's
PostgreSQL database instead, which the stations fill with `station sync`: one
indexed query per listing, whatever the number of sessions.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from datetime import date
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import HTTPException

from procedures.integral_precession.identify import METHODS, identify
from station.engine.registry import ProcedureError, get_procedure
from station.procedure_names import current_name
from station.session import Session
from station.session_lock import recover_interrupted
from station.store import SessionStore, StoreError
from web.config import CentralEntry, StationEntry

if TYPE_CHECKING:  # the central history needs the [fleet] extra: imported only when configured
    from station.central.reader import CentralStore

OUTCOMES = ("running", "finished", "aborted", "failed", "imported", "interrupted")
LONG_LIST = 20  # measurement values longer than this are shown by their length
REPORT_CACHE = 8


@dataclass(frozen=True)
class SessionFilter:
    serial: str = ""  # part of the instrument serial, any case
    procedure: str = ""
    outcome: str = ""
    since: date | None = None
    until: date | None = None
    station: str = ""

    def admits(self, row: dict) -> bool:
        day = date.fromisoformat(row["created_utc"][:10])
        return (
            self.serial.lower() in row["instrument_serial"].lower()
            and (not self.procedure or current_name(row["procedure"]) == current_name(self.procedure))
            and (not self.outcome or row["status"] == self.outcome)
            and (self.since is None or day >= self.since)
            and (self.until is None or day <= self.until)
            and (not self.station or self.station in row["stations"])
        )


@dataclass
class _Store:
    store: SessionStore | CentralStore
    stations: list[StationEntry]


class History:
    """Read side of every configured store."""

    def __init__(self, stations: Iterable[StationEntry], central: CentralEntry | None = None) -> None:
        stations = list(stations)
        self._stores: dict[Path, _Store] = {}
        self._entries = {e.name: e for e in stations}
        self._central: CentralStore | None = None
        if central is not None:
            from station.central.reader import CentralStore

            self._central = CentralStore(central.url, central.arrays)
            stations = []  # the stations' own stores are their journals; the central history is what is read
        for entry in stations:
            key = entry.store.resolve()
            if key not in self._stores:
                local = SessionStore(entry.store)
                self._stores[key] = _Store(local, [])
                recover_interrupted(local)  # running with no live process: interrupted
            self._stores[key].stations.append(entry)
        self._reports: OrderedDict[str, str] = OrderedDict()
        self._lock = threading.Lock()

    def close(self) -> None:
        for s in self._stores.values():
            s.store.close()
        if self._central is not None:
            self._central.close()

    def _central_row(self, row: dict) -> dict:
        return {k: v for k, v in row.items() if k != "station"} | {"stations": [row["station"]]}

    def sessions(self, where: SessionFilter, limit: int) -> list[dict]:
        """Matching sessions, newest first."""
        if self._central is not None:
            from station.central.reader import HistoryQuery

            q = HistoryQuery(where.serial, where.procedure, where.outcome, where.station, where.since, where.until)
            return [self._central_row(r) for r in self._central.history(q, limit)]
        rows = []
        for s in self._stores.values():
            names = [e.name for e in s.stations]
            rows += [row | {"stations": names} for row in s.store.sessions()]
        rows = [r for r in rows if where.admits(r)]
        rows.sort(key=lambda r: r["created_utc"], reverse=True)
        return rows[:limit]

    def _find(self, uid: str) -> _Store:
        if self._central is not None:
            try:
                station = self._central.row(uid)["station"]
            except StoreError:
                raise HTTPException(404, f"no session {uid!r} in the central history") from None
            return _Store(self._central, [self._entries[station]] if station in self._entries else [])
        for s in self._stores.values():
            try:
                s.store.session_config(uid)
            except StoreError:
                continue
            return s
        raise HTTPException(404, f"no session {uid!r} in the stations' stores")

    def load(self, uid: str, *, with_raw: bool = False) -> Session:
        return self._find(uid).store.load_session(uid, with_raw=with_raw)

    def row(self, uid: str) -> dict:
        s = self._find(uid)
        if self._central is not None:  # the central history is then the only store
            return self._central_row(self._central.row(uid))
        assert isinstance(s.store, SessionStore)  # no central history: one of the stations' own stores
        row = next(r for r in s.store.sessions() if r["uid"] == uid)
        if row["status"] == "running" and uid in recover_interrupted(s.store):  # crashed since the panel started
            row = next(r for r in s.store.sessions() if r["uid"] == uid)
        return row | {"stations": [e.name for e in s.stations]}

    def record(self, uid: str) -> dict:
        """Everything the session page shows but the plots: row, configuration, results, events, points."""
        s = self._find(uid)
        session = s.store.load_session(uid, with_raw=False)
        return {
            "session": self.row(uid),
            "config": s.store.session_config(uid),
            "results": s.store.results(uid),
            "events": s.store.events(uid),
            "points": [asdict(p) for p in session.points],
            "measurements": [
                {"key": m.key, "kind": m.kind, "values": {k: _shown(v) for k, v in m.values.items()}}
                for m in session.measurements
            ],
            "station": asdict(session.station),
        }

    def residuals(self, uid: str) -> dict:
        """Residuals of each identification method by vibration point (the report's Figs. 10-11), or why not."""
        session = self.load(uid)
        out: dict[str, dict[str, Any]] = {}
        for method in METHODS:
            try:
                r = identify(session, method)
            except (ValueError, KeyError, IndexError) as exc:  # FitError and kin: nothing to identify here
                out[method] = {"error": str(exc) or type(exc).__name__}
                continue
            out[method] = {"point_ids": list(r.vib_ids), "residuals_radps": r.Y_residuals.tolist(),
                           "proportional_residuals": r.proportional_residuals.tolist()}  # fmt: skip
        return out

    def certificate(self, uid: str, suffix: str = ".html") -> Path:
        """The calibration certificate that the station's analysis wrote beside the report (certificate-UID.html
        and .pdf, procedures.common.certificate); 404 when there is none."""
        for entry in self._find(uid).stations:
            path = entry.reports / f"certificate-{uid}{suffix}"
            if path.is_file():
                return path
        raise HTTPException(404, f"session {uid}: no certificate{suffix} (its procedure issues none, or its "
                            "analysis has not written one)")  # fmt: skip

    def report_html(self, uid: str) -> str:
        """The report the station wrote, else the procedure's analysis of the stored session (kept for a while)."""
        s = self._find(uid)
        for entry in s.stations:
            path = entry.reports / f"report-{uid}.html"
            if path.is_file():
                return path.read_text()
        with self._lock:
            if uid in self._reports:
                return self._reports[uid]
        row = self.row(uid)
        if row["status"] == "running":
            raise HTTPException(409, f"session {uid} is still running: its report is written when it finishes")
        try:
            spec = get_procedure(row["procedure"])
        except ProcedureError:
            spec = None
        if spec is None or spec.analyse is None:
            raise HTTPException(404, f"session {uid}: procedure {row['procedure']!r} has no analysis report")
        try:
            html = spec.analyse(s.store.load_session(uid, with_raw=False)).report_html
        except ValueError as exc:
            raise HTTPException(409, f"session {uid}: no report, the analysis failed: {exc}") from None
        with self._lock:
            self._reports[uid] = html
            while len(self._reports) > REPORT_CACHE:
                self._reports.popitem(last=False)
        return html


def _shown(value):
    return f"[{len(value)} values]" if isinstance(value, list) and len(value) > LONG_LIST else value
