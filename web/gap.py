"""Sim-to-real gap diagnoses run by the panel (station.gap.api.diagnose), kept for a while for their pages.

A diagnosis takes seconds of CPU: one runs at a time, off the event loop,
and the last few are kept by id (`session-<uid>` or `upload-<random>`).
"""

from __future__ import annotations

import secrets
import threading
from collections import OrderedDict
from pathlib import Path

from fastapi import HTTPException

from station.gap.api import diagnose
from station.gap.report import GapReport
from station.session import Session
from station.twin.config import TwinConfig, default_twin

KEPT = 8


def diagnosed(session: Session) -> dict:
    """Which session a diagnosis is of, as its page names it: uid, procedure, instrument, created, points."""
    meta, prov = session.meta, session.provenance
    return {"uid": meta.get("store_uid") or "", "procedure": meta.get("procedure") or "",
            "instrument_serial": meta.get("instrument_serial") or prov.get("instrument_serial") or "",
            "created_utc": prov.get("created_utc") or "", "n_points": len(session.points)}  # fmt: skip


class GapDiagnoses:
    """Runs diagnoses against the panel's twin and keeps the latest ones."""

    def __init__(self, twin_path: Path | None = None) -> None:
        self.twin: TwinConfig = TwinConfig.from_toml(twin_path) if twin_path else default_twin()
        self._reports: OrderedDict[str, tuple[GapReport, dict]] = OrderedDict()  # id -> (report, diagnosed())
        self._lock = threading.Lock()
        self._running = threading.Lock()
        self.last_elapsed_s: float | None = None  # how long the last diagnosis took: what the page expects

    @property
    def running(self) -> bool:
        return self._running.locked()

    def run(self, session: Session, key: str | None = None) -> tuple[str, GapReport, dict]:
        """Diagnose (blocking); (id, report, which session). 422 with the diagnosis' own message when the input
        cannot be used."""
        key = key or f"upload-{secrets.token_hex(8)}"
        with self._running:
            try:
                report = diagnose(session, self.twin)
            except ValueError as exc:  # GapInputError, FitError: the session cannot be compared with the twin
                raise HTTPException(422, f"gap diagnosis: {exc}") from None
            self.last_elapsed_s = report.elapsed_s
        with self._lock:
            self._reports[key] = (report, diagnosed(session))
            self._reports.move_to_end(key)
            while len(self._reports) > KEPT:
                self._reports.popitem(last=False)
        return key, report, diagnosed(session)

    def kept(self, key: str) -> tuple[GapReport, dict] | None:
        """(report, which session) of a kept diagnosis, or None."""
        with self._lock:
            return self._reports.get(key)

    def get(self, key: str) -> tuple[GapReport, dict]:
        kept = self.kept(key)
        if kept is None:
            raise HTTPException(404, f"no gap diagnosis {key!r} kept: run it again")
        return kept
