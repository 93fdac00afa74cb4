"""Live view: the stations, their status and library, and telemetry relayed over a WebSocket."""

from __future__ import annotations

import asyncio
import contextlib
import json
import shlex
from typing import Annotated
from urllib.parse import urlsplit

import anyio
from fastapi import APIRouter, Depends, Query, Request, WebSocket, WebSocketDisconnect

from web.auth import REVOCATION_CHECK_S, SESSION_COOKIE, LoginSessions, viewer
from web.config import StationEntry
from web.relay import BrowserQueue
from web.schemas import RelayHealth, StationSummary, errors
from web.state import Link, Panel, panel

router = APIRouter(tags=["live"])
BATCH = 64  # messages per WebSocket frame at most
RELAY_REPORT_S = 1.0  # how often a browser hears its own drop count and the feeds' health
NOT_LOGGED_IN, CROSS_SITE = 4401, 4403  # WebSocket close codes


@router.get("/api/stations", dependencies=[Depends(viewer)], responses=errors(401))
def stations(request: Request) -> list[StationSummary]:
    """The configured stations and what the panel hears from each."""
    p = panel(request)
    return [StationSummary(name=s.name, title=s.title or s.name, relay=p.relay.feeds[s.name].stats(),
                           serve_command=serve_command(s)) for s in p.config.stations]  # fmt: skip


def serve_command(s: StationEntry) -> str:
    """`station serve` with this entry's name, endpoints, store and reports: what the panel shows a station that
    is not served."""
    args = ["station", "serve", "--name", s.name, "--out", str(s.reports), "--db", str(s.store), "--control",
            s.control, "--telemetry", s.telemetry]  # fmt: skip
    if s.token_env:
        args += ["--token-env", s.token_env]
    return shlex.join(args)


ASK_ERRORS = errors(401, 404, 409, 422, 502, 504)


@router.get("/api/stations/{name}/status", dependencies=[Depends(viewer)], responses=ASK_ERRORS)
async def status(link: Link) -> dict:
    """The station's state and progress, asked over its control channel."""
    return await link.request("status")


@router.get("/api/stations/{name}/library", dependencies=[Depends(viewer)], responses=ASK_ERRORS)
async def library(link: Link) -> list[dict]:
    """The station's procedures with their declared parameters (name, kind, default, min, max, choices, unit)."""
    return await link.request("library")


@router.get("/api/relay", dependencies=[Depends(viewer)], responses=errors(401))
def relay(request: Request) -> RelayHealth:
    """Browsers connected to the telemetry WebSocket, and messages dropped for slow ones since the panel started."""
    r = panel(request).relay
    return RelayHealth(browsers=r.browsers, dropped=r.dropped, queue_size=r.queue_size)


def _same_origin(ws: WebSocket) -> bool:
    """Browsers send Origin with a WebSocket handshake; another site's page must not read the telemetry."""
    origin = ws.headers.get("origin")
    return origin is None or urlsplit(origin).netloc == ws.headers.get("host")


def _relay_report(p: Panel, queue: BrowserQueue) -> str:
    feeds = {n: f.stats() for n, f in p.relay.feeds.items() if queue.stations is None or n in queue.stations}
    return json.dumps({"topic": "relay", "data": {"dropped": queue.dropped, "feeds": feeds}})


async def _pump(ws: WebSocket, queue: BrowserQueue) -> None:
    while True:
        batch = await queue.batch(BATCH)
        await ws.send_text("[" + ",".join(batch) + "]")


async def _report(p: Panel, queue: BrowserQueue) -> None:
    while True:
        queue.offer(_relay_report(p, queue))
        await asyncio.sleep(RELAY_REPORT_S)


async def _until_closed(ws: WebSocket) -> None:
    while True:
        await ws.receive_text()


async def _until_revoked(ws: WebSocket, logins: LoginSessions, token: str | None) -> None:
    """Close the socket once its login ends (logout, expiry, the user removed or re-roled)."""
    while logins.get(token) is not None:
        await asyncio.sleep(REVOCATION_CHECK_S)
    await ws.close(NOT_LOGGED_IN, "logged out")


@router.websocket("/ws/telemetry")
async def telemetry(ws: WebSocket, station: Annotated[list[str] | None, Query()] = None) -> None:
    """Every message of the stations (all, or those named by ?station=), as JSON arrays of telemetry documents."""
    p: Panel = ws.app.state.panel
    token = ws.cookies.get(SESSION_COOKIE)
    if p.logins.get(token) is None:
        await ws.close(NOT_LOGGED_IN, "not logged in")
        return
    if not _same_origin(ws):
        await ws.close(CROSS_SITE, "cross-site WebSocket refused")
        return
    await ws.accept()
    queue = p.relay.subscribe(station)
    try:
        async with anyio.create_task_group() as tasks:

            async def until_first_ends(work) -> None:  # a closed socket ends the pump and the reports too
                with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
                    await work
                tasks.cancel_scope.cancel()

            for work in (_pump(ws, queue), _report(p, queue), _until_closed(ws), _until_revoked(ws, p.logins, token)):
                tasks.start_soon(until_first_ends, work)
    finally:
        p.relay.unsubscribe(queue)
