"""Gap diagnosis pages' API: diagnose a stored session or an uploaded piga-session/1 archive; the HTML report."""

from __future__ import annotations

import tempfile
from pathlib import Path as FsPath
from typing import Annotated

from fastapi import APIRouter, Depends, File, HTTPException, Path, Request, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse

from station.gap.heldout import shrink
from station.gap.report import GapReport, render
from station.interchange import SessionFormatError
from web.archive import unpack
from web.auth import ViewerAction, viewer
from web.schemas import UID_PATTERN, GapReply, GapStatus, errors
from web.state import panel

router = APIRouter(tags=["gap"])


def _reply(key: str, report: GapReport, session: dict) -> GapReply:
    return GapReply(id=key, session=session, report=report.to_json(),
                    shrink=shrink(report.gap_before, report.gap_after))  # fmt: skip


GapId = Annotated[str, Path(pattern=r"^(session|upload)-[A-Za-z0-9_-]{1,64}$", description="id of a kept diagnosis")]
Uid = Annotated[str, Path(pattern=UID_PATTERN, description="session uid")]
Archive = Annotated[UploadFile, File(description="zip of a piga-session/1 directory")]


@router.get("/api/sessions/{uid}/gap", dependencies=[Depends(viewer)], responses=errors(401, 404, 409, 422))
async def diagnose_session(request: Request, uid: Uid) -> GapReply:
    """Diagnose a stored session against the panel's twin (kept until the session changes)."""
    p = panel(request)
    row = await run_in_threadpool(p.history.row, uid)
    if row["status"] == "running":
        raise HTTPException(409, f"session {uid} is still running: diagnose it once it ends")
    key = f"session-{uid}"
    kept = p.gaps.kept(key)
    if kept is not None and kept[0].session_info["n_points"] == row["n_points"]:
        return _reply(key, *kept)
    session = await run_in_threadpool(p.history.load, uid, with_raw=True)
    return _reply(*await run_in_threadpool(p.gaps.run, session, key))


def _diagnose_upload(request: Request, archive: UploadFile) -> tuple[str, GapReport, dict]:
    with tempfile.TemporaryDirectory(prefix="panel-upload-") as tmp:
        try:
            session = unpack(archive.file, FsPath(tmp))
        except SessionFormatError as exc:
            raise HTTPException(422, f"piga-session/1 upload: {exc}") from None
        return panel(request).gaps.run(session)


@router.post("/api/gap", responses=errors(400, 401, 403, 422))
async def diagnose_upload(request: Request, archive: Archive, who: ViewerAction) -> GapReply:
    """Diagnose an uploaded piga-session/1 session (a zip of its directory) against the panel's twin."""
    key, report, session = await run_in_threadpool(_diagnose_upload, request, archive)
    panel(request).audit.record(who.user.name, "gap_upload", file=archive.filename, id=key)
    return _reply(key, report, session)


@router.get("/api/gap/status", dependencies=[Depends(viewer)], responses=errors(401))
def gap_status(request: Request) -> GapStatus:
    """Whether a diagnosis is running, and how long the last one took (what a waiting page can expect)."""
    gaps = panel(request).gaps
    return GapStatus(running=gaps.running, last_elapsed_s=gaps.last_elapsed_s)


@router.get("/api/gap/{gap_id}", dependencies=[Depends(viewer)], responses=errors(401, 404, 422))
def kept_diagnosis(request: Request, gap_id: GapId) -> GapReply:
    """A kept diagnosis."""
    return _reply(gap_id, *panel(request).gaps.get(gap_id))


@router.get("/api/gap/{gap_id}/report", response_class=HTMLResponse, dependencies=[Depends(viewer)],
            responses=errors(401, 404, 422))  # fmt: skip
def gap_report(request: Request, gap_id: GapId) -> HTMLResponse:
    """The self-contained HTML report of a kept diagnosis (maps, ranked effects, held-out shrink)."""
    return HTMLResponse(render(panel(request).gaps.get(gap_id)[0]))
