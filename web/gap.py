"""Sim-to-real gap diagnoses run by the panel (gap.api.diagnose), kept for a while for their pages.

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


class GapDiagnoses:
    """Runs diagnoses against the panel's twin and keeps the latest ones."""

    def __init__(self, twin_path: Path | None = None) -> None:
        self.twin: TwinConfig = TwinConfig.from_toml(twin_path) if twin_path else default_twin()
        self._reports: OrderedDict[str, GapReport] = OrderedDict()
        self._lock = threading.Lock()
        self._running = threading.Lock()

    def run(self, session: Session, key: str | None = None) -> tuple[str, GapReport]:
        """Diagnose (blocking); (id, report). 422 with the diagnosis' own message when the input cannot be used."""
        key = key or f"upload-{secrets.token_hex(8)}"
        with self._running:
            try:
                report = diagnose(session, self.twin)
            except ValueError as exc:  # GapInputError, FitError: the session cannot be compared with the twin
                raise HTTPException(422, f"gap diagnosis: {exc}") from None
        with self._lock:
            self._reports[key] = report
            self._reports.move_to_end(key)
            while len(self._reports) > KEPT:
                self._reports.popitem(last=False)
        return key, report

    def kept(self, key: str) -> GapReport | None:
        with self._lock:
            return self._reports.get(key)

    def get(self, key: str) -> GapReport:
        report = self.kept(key)
        if report is None:
            raise HTTPException(404, f"no gap diagnosis {key!r} kept: run it again")
        return report
