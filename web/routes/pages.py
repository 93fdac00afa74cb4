"""The panel's pages: one shell around each page's content, whose script reads the API; anonymous visitors log in."""

from __future__ import annotations

from functools import cache
from pathlib import Path as FsPath
from string import Template
from typing import Annotated

from fastapi import APIRouter, Path, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from web.auth import SESSION_COOKIE
from web.schemas import UID_PATTERN
from web.state import panel

PAGES = FsPath(__file__).resolve().parents[1] / "pages"
TITLES = {"login": "Log in", "live": "Live", "history": "History", "session": "Session", "gap": "Gap diagnosis"}
router = APIRouter(include_in_schema=False)


@cache
def _html(name: str) -> str:
    shell = Template((PAGES / "shell.html").read_text())
    return shell.substitute(title=TITLES[name], script=name, main=(PAGES / f"{name}.html").read_text())


def _page(request: Request, name: str) -> Response:
    if panel(request).logins.get(request.cookies.get(SESSION_COOKIE)) is None:
        return RedirectResponse("/login", status_code=303)
    return HTMLResponse(_html(name))


@router.get("/login")
def login_page() -> HTMLResponse:
    return HTMLResponse(_html("login"))


@router.get("/")
def live_page(request: Request) -> Response:
    return _page(request, "live")


@router.get("/history")
def history_page(request: Request) -> Response:
    return _page(request, "history")


@router.get("/sessions/{uid}")
def session_page(request: Request, uid: Annotated[str, Path(pattern=UID_PATTERN)]) -> Response:
    return _page(request, "session")


@router.get("/gap")
def gap_page(request: Request) -> Response:
    return _page(request, "gap")
