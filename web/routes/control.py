"""Control: dry run, start, pause, resume, abort, emergency stop, reset, resume a session; all in the audit log.

Only operators act (with their CSRF token); a dry run moves nothing and is
open to every logged-in user. Each action is forwarded with the operator's
name, which the station writes into the session's event log.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.concurrency import run_in_threadpool

from web.auth import LoginSession, Operator, ViewerAction, viewer
from web.schemas import ActionReply, PlanRequest, ResumeSessionRequest, StartRequest, errors
from web.state import Link, panel
from web.stations import StationLink

router = APIRouter(tags=["control"])
STATION_ERRORS = errors(400, 401, 403, 404, 409, 422, 502, 504)


async def _act(request: Request, link: StationLink, who: LoginSession, cmd: str, args: dict | None = None) -> Any:
    """Forward one control action with who asked; audit it whatever the station answers."""
    audit = panel(request).audit
    try:
        result = await link.request(cmd, args, user=who.user.name)
    except HTTPException as exc:
        audit.record(who.user.name, cmd, station=link.entry.name, args=args, ok=False, status=exc.status_code,
                     error=exc.detail)  # fmt: skip
        raise
    audit.record(who.user.name, cmd, station=link.entry.name, args=args, ok=True)
    return result


@router.post("/api/stations/{name}/plan", responses=STATION_ERRORS)
async def plan(body: PlanRequest, link: Link, who: ViewerAction) -> dict:
    """Dry run: validate the parameters and every step, and estimate the durations. Nothing moves."""
    return await link.request("plan", body.model_dump(), user=who.user.name)


@router.post("/api/stations/{name}/start", responses=STATION_ERRORS)
async def start(request: Request, body: StartRequest, link: Link, who: Operator) -> ActionReply:
    """Start a procedure of the library after the station's dry run of its design: a design that cannot work is
    refused (422, one line per problem); one with warnings is 409 with the list until the request has confirm."""
    design = {"procedure": body.procedure, "params": body.params}
    warnings = (await _act(request, link, who, "plan", design))["warnings"]
    if warnings and not body.confirm:
        lines = "; ".join(w["line"] for w in warnings)
        raise HTTPException(409, {"message": f"confirm to start this design: {lines}", "warnings": warnings})
    return ActionReply(result=await _act(request, link, who, "start", body.model_dump(exclude={"confirm"})))


@router.post("/api/stations/{name}/resume-session", responses=STATION_ERRORS)
async def resume_session(request: Request, body: ResumeSessionRequest, link: Link, who: Operator) -> ActionReply:
    """Continue an aborted, failed or interrupted session: the measurements it holds are kept, the rest measured."""
    row = await run_in_threadpool(panel(request).history.row, body.uid)  # 404 for a uid the stores do not hold
    if link.entry.name not in row["stations"]:
        raise HTTPException(404, f"session {body.uid} is not in station {link.entry.name}'s store")
    if row["status"] not in ("aborted", "failed", "interrupted"):
        raise HTTPException(409, f"session {body.uid} is {row['status']}: only an aborted, failed or interrupted one "
                            "can be resumed")  # fmt: skip
    return ActionReply(result=await _act(request, link, who, "resume_session", body.model_dump()))


def _simple(cmd: str, doc: str):
    async def action(request: Request, link: Link, who: Operator) -> ActionReply:
        return ActionReply(result=await _act(request, link, who, cmd))

    action.__doc__ = doc
    action.__name__ = cmd
    return action


for _cmd, _doc in (
    ("pause", "Pause at the next safe point (before a measurement or at a checkpoint)."),
    ("resume", "Resume a paused run."),
    ("abort", "Abort: the open window is aborted, the table ramps to rest, the session keeps what it measured."),
    ("estop", "Emergency stop: quick stop of the crank and the head held now, then the procedure ends."),
    ("reset", "After an emergency stop or a drive fault, once its cause is removed: fault reset, head released."),
):
    router.add_api_route(f"/api/stations/{{name}}/{_cmd}", _simple(_cmd, _doc), methods=["POST"],
                         responses=STATION_ERRORS, response_model=ActionReply)  # fmt: skip


@router.get("/api/audit", dependencies=[Depends(viewer)], responses=errors(401, 422))
def audit(request: Request, limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[dict]:
    """The panel's audit log, newest last: control actions and logins, who and when."""
    return panel(request).audit.tail(limit)
