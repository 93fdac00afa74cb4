"""History: sessions with filters, a session's record and residuals, its HTML report and piga-session/1 download."""

from __future__ import annotations

import re
import shutil
from datetime import date
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Path, Query, Request
from fastapi.responses import FileResponse, HTMLResponse
from pydantic import BeforeValidator
from starlette.background import BackgroundTask

from web.archive import pack
from web.auth import viewer
from web.history import OUTCOMES, SessionFilter
from web.schemas import UID_PATTERN, SessionRow, errors
from web.state import panel

router = APIRouter(prefix="/api/sessions", tags=["history"], dependencies=[Depends(viewer)])
Uid = Annotated[str, Path(pattern=UID_PATTERN, description="session uid")]


def _iso_day(value: object) -> object:
    """Only YYYY-MM-DD: pydantic alone would also read a number as a Unix time."""
    if not (isinstance(value, str) and re.fullmatch(r"\d{4}-\d{2}-\d{2}", value)):
        raise ValueError("expected a date as YYYY-MM-DD")
    return value


Day = Annotated[date, BeforeValidator(_iso_day)]


@router.get("", responses=errors(401, 422), response_model=list[SessionRow])
def sessions(
    request: Request,
    serial: Annotated[str, Query(max_length=64, description="part of the instrument serial (any case)")] = "",
    procedure: Annotated[str, Query(max_length=200, description="procedure name")] = "",
    outcome: Annotated[Literal[("", *OUTCOMES)], Query(description="session status")] = "",  # type: ignore[valid-type]
    since: Annotated[Day | None, Query(description="created on or after (UTC date, YYYY-MM-DD)")] = None,
    until: Annotated[Day | None, Query(description="created on or before (UTC date, YYYY-MM-DD)")] = None,
    station: Annotated[str, Query(max_length=40, description="station name")] = "",
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
) -> list[dict]:
    """Sessions of every station's store, newest first."""
    where = SessionFilter(serial, procedure, outcome, since, until, station)
    return panel(request).history.sessions(where, limit)


@router.get("/{uid}", responses=errors(401, 404, 422))
def session(request: Request, uid: Uid) -> dict:
    """The session, its configuration, identified coefficients with uncertainties, events and points."""
    return panel(request).history.record(uid)


@router.get("/{uid}/residuals", responses=errors(401, 404, 422))
def residuals(request: Request, uid: Uid) -> dict:
    """Residuals and proportional residuals of each identification method by vibration point."""
    return panel(request).history.residuals(uid)


@router.get("/{uid}/report", response_class=HTMLResponse, responses=errors(401, 404, 409, 422))
def report(request: Request, uid: Uid) -> HTMLResponse:
    """The self-contained HTML report of a finished session."""
    return HTMLResponse(panel(request).history.report_html(uid))


@router.get("/{uid}/certificate", response_class=FileResponse, responses=errors(401, 404, 422))
def certificate(request: Request, uid: Uid) -> FileResponse:
    """The session's calibration certificate as HTML, as its analysis wrote it."""
    return FileResponse(panel(request).history.certificate(uid, ".html"), media_type="text/html")


@router.get("/{uid}/certificate.pdf", response_class=FileResponse, responses=errors(401, 404, 422))
def certificate_pdf(request: Request, uid: Uid) -> FileResponse:
    """The session's calibration certificate as PDF."""
    return FileResponse(panel(request).history.certificate(uid, ".pdf"), media_type="application/pdf",
                        filename=f"certificate-{uid}.pdf")  # fmt: skip


@router.get("/{uid}/export", response_class=FileResponse, responses=errors(401, 404, 422))
def export(request: Request, uid: Uid) -> FileResponse:
    """The session as a piga-session/1 directory in a zip archive."""
    name = f"session-{uid}"
    archive = pack(panel(request).history.load(uid, with_raw=True), name)
    return FileResponse(archive, media_type="application/zip", filename=f"{name}.zip",
                        background=BackgroundTask(shutil.rmtree, archive.parent, ignore_errors=True))  # fmt: skip
