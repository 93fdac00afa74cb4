"""Who is looking and who may act: cookie login sessions, roles and CSRF tokens.

A login gives a random session token in an HttpOnly, SameSite=Strict cookie
and a CSRF token that the page sends back in the X-CSRF-Token header with
every request that changes something (synchronizer-token pattern). Both live
only in the panel's memory, the session token as its SHA-256: a restart logs
everybody out, and nothing secret is ever written down.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, HTTPException, Request, Security
from fastapi.security import APIKeyCookie, APIKeyHeader

from web.users import User

SESSION_COOKIE = "panel_session"
CSRF_HEADER = "X-CSRF-Token"
IDLE_LIMIT_S = 12 * 3600.0  # a 7-hour session watched from one login


@dataclass
class LoginSession:
    user: User
    csrf: str = field(default_factory=lambda: secrets.token_urlsafe(32))
    last_seen: float = field(default_factory=time.monotonic)


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class LoginSessions:
    """Open logins by the hash of their cookie token; idle ones expire."""

    def __init__(self, idle_limit_s: float = IDLE_LIMIT_S) -> None:
        self.idle_limit_s = idle_limit_s
        self._by_digest: dict[str, LoginSession] = {}
        self._lock = threading.Lock()

    def open(self, user: User) -> tuple[str, LoginSession]:
        """A new cookie token and its session."""
        token = secrets.token_urlsafe(32)
        session = LoginSession(user)
        with self._lock:
            self._by_digest[_digest(token)] = session
        return token, session

    def get(self, token: str | None) -> LoginSession | None:
        if not token:
            return None
        now = time.monotonic()
        with self._lock:
            session = self._by_digest.get(_digest(token))
            if session is None:
                return None
            if now - session.last_seen > self.idle_limit_s:
                del self._by_digest[_digest(token)]
                return None
            session.last_seen = now
            return session

    def close(self, token: str | None) -> None:
        if token:
            with self._lock:
                self._by_digest.pop(_digest(token), None)


_cookie = APIKeyCookie(name=SESSION_COOKIE, auto_error=False, description="login session (POST /api/login)")
_csrf = APIKeyHeader(name=CSRF_HEADER, auto_error=False, description="CSRF token of the login (GET /api/me)")
CookieToken = Annotated[str | None, Security(_cookie)]
CsrfToken = Annotated[str | None, Security(_csrf)]


def login_sessions(request: Request) -> LoginSessions:
    return request.app.state.panel.logins


def viewer(request: Request, token: CookieToken) -> LoginSession:
    """Any logged-in user (viewer or operator); 401 otherwise."""
    session = login_sessions(request).get(token)
    if session is None:
        raise HTTPException(401, "not logged in: POST /api/login first")
    return session


Viewer = Annotated[LoginSession, Depends(viewer)]


def _check_csrf(session: LoginSession, csrf: str | None) -> None:
    if csrf is None or not hmac.compare_digest(csrf, session.csrf):
        raise HTTPException(403, f"missing or wrong CSRF token: send the {CSRF_HEADER} header given by GET /api/me")


def viewer_action(session: Viewer, csrf: CsrfToken) -> LoginSession:
    """A logged-in user's request that changes something (logout, a dry run, a diagnosis): CSRF token required."""
    _check_csrf(session, csrf)
    return session


def operator(session: Viewer, csrf: CsrfToken) -> LoginSession:
    """An operator's request with its CSRF token; 403 for viewers."""
    if session.user.role != "operator":
        raise HTTPException(403, f"operators only: {session.user.name} is a {session.user.role}")
    _check_csrf(session, csrf)
    return session


ViewerAction = Annotated[LoginSession, Depends(viewer_action)]
Operator = Annotated[LoginSession, Depends(operator)]
