"""The station's sessions in a notebook: `station.open_store(path)` and pandas DataFrames.

    import station
    store = station.open_store("out/station.sqlite")
    store.sessions                      # one row per session
    s = store.session()                 # the latest finished one, named (store.session(uid), store[uid])
    s.points, s.measurements, s.events  # DataFrames
    s.results                           # one row per coefficient: value, u, U = k u, unit
    s.result("integral")                # rich display in Jupyter: coefficients with units, the fit check (mu vs mu_c)
    s.gap()                             # the sim-to-real gap diagnosis (station.gap.report.GapReport, rich display too)

Everything is read from the store (SQLite WAL: safe while a station writes). Units are in the
column names (`_s`, `_hz`, `_deg`, `_radps`); u is the standard uncertainty (k = 1) and U = k u the
expanded one with its coverage factor k (station.coefficients says where each comes from).
"""

from __future__ import annotations

import html
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from station.coefficients import MU_NOTE, UNCERTAINTY_NOTE, CoefficientRow, coefficient_rows, conclusion
from station.errors import InputError
from station.extras import needs_extra
from station.session import Session
from station.store import SessionStore

with needs_extra("station.open_store (the notebook API)"):
    import pandas as pd

POINT_COLUMNS = ("point_id", "sequence", "start_s", "position_deg", "freq_hz", "kind", "pulses", "Tm_s", "t1_s",
                 "t2_s", "Np")  # fmt: skip
RESULT_COLUMNS = ("result", "coefficient", "value", "u", "k", "U", "unit", "u_relative", "u_fit", "budgeted", "note")


def open_store(path: str | Path) -> Store:
    """The session store at `path` (an existing SQLite file made by the station)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"open_store: {path}: no session store there (a station run, `station import` or "
                         "`station serve` makes one)")  # fmt: skip
    return Store(SessionStore(path))


def _table_html(frame: pd.DataFrame) -> str:
    return frame.to_html(index=False, na_rep="—", float_format=lambda x: f"{x:.6g}", border=0)


class Store:
    """A session store, read for analysis."""

    def __init__(self, store: SessionStore) -> None:
        self._store = store
        self.path = store.path

    def close(self) -> None:
        self._store.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def sessions(self) -> pd.DataFrame:
        """One row per session: uid, created_utc, procedure, instrument_serial, status, n_points, n_measurements."""
        rows = self._store.sessions()
        columns = ("uid", "created_utc", "procedure", "instrument_serial", "status", "n_points", "n_measurements")
        return pd.DataFrame(rows, columns=list(columns))

    def session(self, uid: str | None = None, *, status: str | None = "finished") -> StoredSession:
        """The session `uid`, or else the latest one of `status` (default: the latest finished one; None: the
        latest whatever its status), saying which it took (a failed run's session has no results to show)."""
        rows = self._store.sessions()
        if not rows:
            raise InputError(f"{self.path}: the store holds no session")
        if uid is None:
            fitting = [r for r in rows if status is None or r["status"] == status]
            if not fitting:
                held = ", ".join(sorted({str(r["status"]) for r in rows}))
                raise InputError(f"{self.path}: no {status} session (the store holds {held} ones: pass "
                                 "status=... or None for the latest of any, or a uid)")  # fmt: skip
            r = fitting[-1]
            which = f"the latest {status}" if status is not None else "the latest"
            print(f"session {r['uid']}: {which} of {len(rows)} in the store ({r['procedure']}, {r['status']}, "
                  f"{r['created_utc']}); store.session(uid) for another")  # fmt: skip
            return StoredSession(self._store, r["uid"])
        if uid not in {r["uid"] for r in rows}:
            raise InputError(f"session {uid!r}: not in {self.path} (store.sessions lists them)")
        return StoredSession(self._store, uid)

    def __getitem__(self, uid: str) -> StoredSession:
        return self.session(uid)

    def __len__(self) -> int:
        return len(self._store.sessions())

    def _repr_html_(self) -> str:
        return f"<p>Session store <code>{html.escape(str(self.path))}</code></p>" + _table_html(self.sessions)


class StoredSession:
    """One stored session: its points, measurements, events and results as DataFrames."""

    def __init__(self, store: SessionStore, uid: str) -> None:
        self._store = store
        self.uid = uid
        self.config: dict = store.session_config(uid)
        self._session: Session | None = None

    @property
    def info(self) -> dict:
        """The store's row of this session (procedure, serial, status, counts)."""
        return next(r for r in self._store.sessions() if r["uid"] == self.uid)

    def session(self) -> Session:
        """The session itself (station.session.Session, without raw streams), for identify() or the gap diagnosis."""
        if self._session is None:
            self._session = self._store.load_session(self.uid, with_raw=False)
        return self._session

    @property
    def points(self) -> pd.DataFrame:
        """One row per measured window: the recorded columns, `rate_radps` (seed 000 eq. 17) and any extras."""
        s = self.session()
        rows = [{**{c: getattr(p, c) for c in POINT_COLUMNS}, **p.extra} for p in s.points]
        frame = pd.DataFrame(rows, columns=None if rows else list(POINT_COLUMNS))
        for column in frame.columns.difference(POINT_COLUMNS):  # extras are stored as text: numbers where all are
            numbers = pd.to_numeric(frame[column], errors="coerce")
            if numbers.notna().sum() == frame[column].notna().sum():
                frame[column] = numbers
        frame["rate_radps"] = s.rates_radps() if rows else pd.Series(dtype=float)
        return frame

    @property
    def measurements(self) -> pd.DataFrame:
        """One row per other measurement: key, kind and its scalar values (lists and arrays left out)."""
        rows = []
        for m in self.session().measurements:
            scalars = {k: v for k, v in m.values.items() if isinstance(v, int | float | str | bool) or v is None}
            rows.append({"key": m.key, "kind": m.kind, **scalars})
        return pd.DataFrame(rows, columns=None if rows else ["key", "kind"])

    @property
    def events(self) -> pd.DataFrame:
        """The session's event log: t_utc, level, kind, message."""
        return pd.DataFrame(self._store.events(self.uid), columns=["t_utc", "level", "kind", "message"])

    def result_docs(self) -> dict[str, dict]:
        """The stored results by method (the latest of each), as the analysis wrote them."""
        return {r["method"]: r["result"] for r in self._store.results(self.uid)}

    @property
    def results(self) -> pd.DataFrame:
        """One row per identified quantity: value, u (k = 1), the coverage factor k, U = k u, unit, u/|value|,
        u_fit (the fit's Type A alone) and whether u and U come from a GUM budget."""
        return _rows_frame(coefficient_rows(self.result_docs()))

    def result(self, method: str | None = None) -> Result:
        """One method's result (the first stored when None), displayed richly in a notebook."""
        docs = self.result_docs()
        if not docs:
            raise InputError(f"session {self.uid}: no result stored (status {self.info['status']})")
        name = method or next(iter(docs))
        if name not in docs:
            raise InputError(f"session {self.uid}: no result {name!r}; stored: {', '.join(docs)}")
        return Result(name, docs[name], self.uid, self.info["status"])

    def gap(self, twin: Any = None, **options: Any):
        """The sim-to-real gap diagnosis of this session against `twin` (default: the embedded twin);
        a station.gap.report.GapReport, which a notebook displays as the HTML report. Options go to
        station.gap.api.diagnose."""
        from station.gap.api import diagnose
        from station.twin.config import default_twin

        return diagnose(self.session(), twin or default_twin(), **options)

    def _repr_html_(self) -> str:
        i = self.info
        head = (f"<p>Session <b>{html.escape(self.uid)}</b>: {html.escape(str(i['procedure']))}, "
                f"{html.escape(str(i['status']))}, {i['n_points']} points, {i['n_measurements']} measurements, "
                f"instrument {html.escape(str(i['instrument_serial']))}</p>")  # fmt: skip
        docs = self.result_docs()
        return head + (Result.table_html(coefficient_rows(docs)) if docs else "<p>No result stored.</p>")


def _rows_frame(rows: list[CoefficientRow]) -> pd.DataFrame:
    data = [(r.result, r.name, r.value, r.u, r.k, r.expanded, r.unit, r.relative, r.u_fit, r.budgeted, r.note)
            for r in rows]  # fmt: skip
    return pd.DataFrame(data, columns=list(RESULT_COLUMNS))


class Result:
    """One method's stored result: `doc` as written, `frame` its coefficients; rich HTML in a notebook."""

    def __init__(self, method: str, doc: Mapping[str, Any], uid: str = "", status: str = "finished") -> None:
        self.method = method
        self.doc = dict(doc)
        self.uid = uid
        self.status = status

    @property
    def rows(self) -> list[CoefficientRow]:
        return coefficient_rows({self.method: self.doc})

    @property
    def frame(self) -> pd.DataFrame:
        return _rows_frame(self.rows)

    @property
    def conclusion(self) -> list[str]:
        """The run, the fit check and conformity, each a line, as the console prints them
        (station.coefficients.conclusion): no line says ACCEPTED."""
        return conclusion(self.status, {self.method: self.doc})

    @staticmethod
    def table_html(rows: list[CoefficientRow]) -> str:
        cells = []
        for r in rows:
            if r.value is None:
                cells.append(f"<tr><td>{html.escape(r.name)}</td><td colspan=6>not identified "
                             f"{html.escape(r.note)}</td></tr>")  # fmt: skip
                continue
            u = "—" if r.u is None else f"{r.u:.2e}"
            big_u = "—" if r.expanded is None else f"{r.expanded:.2e}"
            k = "—" if r.k is None else f"{r.k:.2f}"
            source = "GUM budget" if r.budgeted else "fit (Type A)"
            cells.append(f"<tr><td>{html.escape(r.name)}</td><td>{r.value:.7e}</td><td>{u}</td><td>{k}</td>"
                         f"<td>{big_u}</td><td>{html.escape(r.unit)}</td><td>{source}</td></tr>")  # fmt: skip
        head = ("<tr><th>coefficient</th><th>value</th><th>u (k = 1)</th><th>k</th><th>U = k u</th><th>unit</th>"
                "<th>u from</th></tr>")  # fmt: skip
        return f"<table>{head}{''.join(cells)}</table>"

    def _repr_html_(self) -> str:
        d = self.doc
        parts = [f"<h4>{html.escape(self.method)}{f' — session {html.escape(self.uid)}' if self.uid else ''}</h4>",
                 self.table_html(self.rows)]  # fmt: skip
        if isinstance(d.get("sigma_residual"), int | float):
            unit = d.get("units", {}).get("sigma_residual", "")
            parts.append(f"<p>residual sigma = {d['sigma_residual']:.3e} {html.escape(unit)}"
                         + (f"; mu = {d['mu']:.2f}, mu_c = {d['mu_c']:.2f}" if "mu" in d else "") + "</p>")  # fmt: skip
        parts.append("<p>" + "<br>".join(html.escape(line) for line in self.conclusion) + "</p>")
        parts.append(f"<p><small>{html.escape(UNCERTAINTY_NOTE)}; {html.escape(MU_NOTE)}</small></p>")
        return "\n".join(parts)

    def __repr__(self) -> str:
        return f"Result({self.method!r}, {len(self.rows)} quantities; {self.conclusion[1]})"
