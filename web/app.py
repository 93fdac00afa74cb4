"""The panel's FastAPI application: `create_app(config)`; `station panel` serves it with uvicorn.

Around everything the application does (its error pages and 500s included), three
plain ASGI layers: ConnectionGivenUp drops quietly a response that the server can no
longer send (no traceback in the panel's log for any request), SecurityHeaders puts
SECURITY_HEADERS on every HTTP response,
AuthBeforeBody answers a request with a body that its route's login, role or CSRF
check refuses (401, 403) before a byte of the body is read (FastAPI reads a
whole body, an upload spooled to disk, before it runs a route's dependencies),
and bounds a body to a route open to anyone (the login) at OPEN_BODY_BYTES; and
BodyLimit answers 413 to a request body over MAX_BODY_BYTES (by
Content-Length, or by counting a chunked body) before any route reads it, and
in place of whatever a route would answer to a body cut at the limit. The
OpenAPI schema is served at /openapi.json to logged-in users only.
"""

from __future__ import annotations

import json
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import asynccontextmanager
from pathlib import Path

import anyio
import h11
from fastapi import Depends, FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from station.errors import StationFault
from web.archive import MAX_UPLOAD_BYTES
from web.auth import admit, gate_of, viewer
from web.config import PanelConfig, describe_errors
from web.routes import auth, control, gap, history, live, pages
from web.state import Panel

HERE = Path(__file__).resolve().parent
# uPlot: shipped in the package at build time (setup.py), or web/setup.sh's npm package in a source tree
UPLOT = next((d for d in (HERE / "vendor" / "uplot", HERE / "node_modules" / "uplot" / "dist") if d.is_dir()),
             HERE / "node_modules" / "uplot" / "dist")  # fmt: skip
# Everything from the panel itself: no page may load anything from elsewhere (labs are often offline).
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
    "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'self'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
}


MAX_BODY_BYTES = MAX_UPLOAD_BYTES + (1 << 20)  # an upload and its multipart envelope
OPEN_BODY_BYTES = 64 << 10  # a body to a route open to anyone (the login's name and password)
LINGER_S = 2.0  # after a 413, what the client still sends is read (and dropped) this long at most
GIVEN_UP_WAIT_S = 1.0  # for the server to close a connection it answered itself (ConnectionGivenUp)


class SecurityHeaders:
    """SECURITY_HEADERS on every HTTP response, whoever wrote it (a route, an error handler, a 500)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self.headers = [(k.lower().encode(), v.encode()) for k, v in SECURITY_HEADERS.items()]

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        names = {k for k, _ in self.headers}

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                kept = [(k, v) for k, v in message.get("headers", []) if k.lower() not in names]
                message = {**message, "headers": kept + self.headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)


class BodyTooLarge(Exception):  # noqa: N818 - a control-flow signal
    """A request body went over MAX_BODY_BYTES while it was read."""


async def refuse(receive: Receive, send: Send, status: int, detail: str) -> None:
    """An error answered without reading the body: then what the client still sends is read and dropped for at
    most LINGER_S before the response ends (and the server may close the connection: closing with the client's
    bytes unread would reset the connection, and a client still sending would lose the answer)."""
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body, "more_body": True})
    with anyio.move_on_after(LINGER_S):
        while (message := await receive())["type"] == "http.request" and message.get("more_body"):
            pass
    await send({"type": "http.response.body", "body": b""})


def _has_body(scope: Scope) -> bool:
    headers = dict(scope.get("headers", []))
    return b"transfer-encoding" in headers or headers.get(b"content-length", b"0").strip() not in (b"0", b"")


def api_routes(routes: list) -> Iterator[APIRoute]:
    """Every APIRoute of an application's routes, those of included routers too (FastAPI keeps an included router
    as a route of its own that holds the original)."""
    for route in routes:
        if isinstance(route, APIRoute):
            yield route
        elif (inner := getattr(route, "original_router", None)) is not None:
            yield from api_routes(inner.routes)


class AuthBeforeBody:
    """A request with a body is let through only once its route's gate (web.auth.gate_of: login, operator role,
    CSRF token, as the route's dependencies declare) admits its headers; otherwise 401 or 403 at once, the body
    unread. A body to a route open to anyone (the login) is bounded at open_max_bytes (413); a body to no route
    known here needs a login (fail closed: 401 rather than 404 for an anonymous one)."""

    def __init__(self, app: ASGIApp, routes: FastAPI, open_max_bytes: int = OPEN_BODY_BYTES) -> None:
        self.app = app
        self.routes = routes
        self.open = BodyLimit(app, open_max_bytes)
        self._gates: list[tuple[APIRoute, Callable[..., object] | None]] | None = None

    def _gate(self, scope: Scope) -> Callable[..., object] | None:
        """The gate of the route the request goes to (None: open to anyone); viewer for no route known."""
        if self._gates is None:  # the routes are all there by the first request
            self._gates = [(r, gate_of(r.dependant)) for r in api_routes(self.routes.router.routes)]
        return next((g for r, g in self._gates if r.matches(scope)[0] == Match.FULL), viewer)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not _has_body(scope):
            await self.app(scope, receive, send)
            return
        gate = self._gate(scope)
        if gate is None:
            await self.open(scope, receive, send)
            return
        try:  # the login book may be read from disk: off the event loop
            await anyio.to_thread.run_sync(admit, Request(scope), gate)
        except HTTPException as exc:
            await refuse(receive, send, exc.status_code, str(exc.detail))
            return
        await self.app(scope, receive, send)


class BodyLimit:
    """413 for a request body over max_bytes, declared (Content-Length) or counted as it arrives."""

    def __init__(self, app: ASGIApp, max_bytes: int = MAX_BODY_BYTES) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _refuse(self, receive: Receive, send: Send) -> None:
        """The 413 (refuse)."""
        mib = f" ({self.max_bytes >> 20} MiB)" if self.max_bytes >> 20 else ""
        await refuse(receive, send, 413, f"request body over {self.max_bytes} bytes{mib}: refused")

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope.get("headers", [])).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            await self._refuse(receive, send)
            return
        seen = 0
        over = started = False

        async def counted() -> Message:
            nonlocal seen, over
            if over:
                raise BodyTooLarge
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    over = True
                    raise BodyTooLarge
            return message

        async def tracked(message: Message) -> None:
            nonlocal started
            if over:  # whatever the application made of the cut body (FastAPI: 400, cannot parse), it is a 413
                if not started:
                    started = True
                    await self._refuse(receive, send)
                return
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, tracked)
        except BodyTooLarge:
            if not started:
                started = True
                await self._refuse(receive, send)


class ConnectionGivenUp:
    """A response the server can no longer send is dropped quietly, not raised as a traceback.

    uvicorn (h11) answers a connection itself when the client breaks HTTP while a request is being handled
    (bytes after a `Connection: close` request, a broken chunk): it sends a 400 and closes, and the route's own
    answer then fails in h11 with LocalProtocolError. That answer cannot reach anyone: it is dropped, and this
    layer waits (at most GIVEN_UP_WAIT_S) for the server to see the connection closed, so that it does not
    report an unfinished response either."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        given_up = False

        async def send_unless_given_up(message: Message) -> None:
            nonlocal given_up
            if given_up:
                return
            try:
                await send(message)
            except h11.LocalProtocolError:
                given_up = True

        await self.app(scope, receive, send_unless_given_up)
        if given_up:
            with anyio.move_on_after(GIVEN_UP_WAIT_S):
                while (await receive())["type"] != "http.disconnect":
                    pass


class PanelApp(FastAPI):
    """FastAPI with the panel's outermost layers (outside even Starlette's 500 handler)."""

    def build_middleware_stack(self) -> ASGIApp:
        return ConnectionGivenUp(SecurityHeaders(AuthBeforeBody(BodyLimit(super().build_middleware_stack()), self)))


class PanelSetupError(StationFault):
    """Something the project's setup installs is missing."""


async def _clear_422(request: Request, exc: RequestValidationError) -> JSONResponse:
    """422 with one readable line per defect (where, what, the value) instead of pydantic's raw list."""
    return JSONResponse({"detail": describe_errors(list(exc.errors()))}, status_code=422)


def create_app(config: PanelConfig) -> FastAPI:
    if not (UPLOT / "uPlot.iife.min.js").is_file():
        raise PanelSetupError(f"{UPLOT} is missing: run web/setup.sh (npm ci in web/) to install uPlot")
    panel = Panel.open(config)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        panel.relay.start()
        try:
            yield
        finally:
            await panel.relay.stop()
            panel.close()

    app = PanelApp(
        title="Station panel",
        version="1",
        description="Live monitoring, history and authenticated control of PIGA calibration stations.",
        lifespan=lifespan,
        exception_handlers={RequestValidationError: _clear_422},
        docs_url=None,  # the interactive docs load their scripts from the internet
        redoc_url=None,
        openapi_url=None,  # served below, to logged-in users only
    )
    app.state.panel = panel

    @app.get("/openapi.json", include_in_schema=False, dependencies=[Depends(viewer)])
    def openapi() -> JSONResponse:
        return JSONResponse(app.openapi())

    for module in (auth, live, control, history, gap, pages):
        app.include_router(module.router)
    app.mount("/static", StaticFiles(directory=HERE / "static"), name="static")
    app.mount("/vendor/uplot", StaticFiles(directory=UPLOT), name="uplot")
    return app
