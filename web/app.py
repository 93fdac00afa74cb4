"""The panel's FastAPI application: `create_app(config)`; `station panel` serves it with uvicorn."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from station.errors import StationFault
from web.config import PanelConfig, describe_errors
from web.routes import auth, control, gap, history, live, pages
from web.state import Panel

HERE = Path(__file__).resolve().parent
UPLOT = HERE / "node_modules" / "uplot" / "dist"
# Everything from the panel itself: no page may load anything from elsewhere (labs are often offline).
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
    "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'self'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
}


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

    app = FastAPI(
        title="Station panel",
        version="1",
        description="Live monitoring, history and authenticated control of PIGA calibration stations.",
        lifespan=lifespan,
        docs_url=None,  # the interactive docs load their scripts from the internet
        redoc_url=None,
    )
    app.state.panel = panel
    app.add_exception_handler(RequestValidationError, _clear_422)

    @app.middleware("http")
    async def security_headers(request: Request, call_next):
        response = await call_next(request)
        response.headers.update(SECURITY_HEADERS)
        return response

    for module in (auth, live, control, history, gap, pages):
        app.include_router(module.router)
    app.mount("/static", StaticFiles(directory=HERE / "static"), name="static")
    app.mount("/vendor/uplot", StaticFiles(directory=UPLOT), name="uplot")
    return app
