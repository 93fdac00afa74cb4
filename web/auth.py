"""Who is looking and who may act: cookie login sessions, roles and CSRF tokens.

A login gives a random session token in an HttpOnly, SameSite=Strict cookie
and a CSRF token that the page sends back in the X-CSRF-Token header with
every request that changes something (synchronizer-token pattern). Both live
only in the panel's memory, the session token as its SHA-256: a restart logs
everybody out, and nothing secret is ever written down.

Every request checks its login against the users file as it is now
(web.users.LiveUsers): a user removed (or removed and added again), whose role
or password changed, is logged out on their next request, and their open
WebSockets are closed within REVOCATION_CHECK_S (web.routes.live).

Logins are throttled (LoginThrottle) by address, and by user name from one
address: after MAX_FAILURES wrong passwords within FAILURE_WINDOW_S for one name
from one address, or from one address whatever the names, that pair or address
is refused with 429 for the rest of the window before any password is checked.
Nobody can lock a user out by guessing their password from elsewhere: the
operator's own address is never counted against them (a lock per name alone
would let anyone do it with MAX_FAILURES requests). The price: an attacker
with many addresses gets MAX_FAILURES guesses per address and window, each an
Argon2id verification. The address is the TCP peer's, or the client that a
configured trusted proxy names in X-Forwarded-For (PanelConfig.trusted_proxies;
none by default). The audit records each failure up to the limit and the first
refusal of each window, so a password-guessing flood cannot fill it.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, HTTPException, Request, Security
from fastapi.dependencies.models import Dependant
from fastapi.security import APIKeyCookie, APIKeyHeader

from station.clock import host_clock
from web.users import LiveUsers, User

SESSION_COOKIE = "panel_session"
CSRF_HEADER = "X-CSRF-Token"
IDLE_LIMIT_S = 12 * 3600.0  # a 7-hour session watched from one login
REVOCATION_CHECK_S = 0.5  # how often an open WebSocket's login is checked again
MAX_FAILURES = 5  # wrong passwords per user name from one address, and per address, within the window (default)
FAILURE_WINDOW_S = 15 * 60.0
THROTTLE_KEYS = 10_000  # names and addresses remembered at most (the oldest forgotten first)


@dataclass
class LoginSession:
    user: User
    csrf: str = field(default_factory=lambda: secrets.token_urlsafe(32))
    last_seen: float = field(default_factory=lambda: host_clock().now_s())


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class LoginSessions:
    """Open logins by the hash of their cookie token; idle ones expire."""

    def __init__(self, idle_limit_s: float = IDLE_LIMIT_S, users: LiveUsers | None = None) -> None:
        self.idle_limit_s = idle_limit_s
        self.users = users
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
        now = host_clock().now_s()
        with self._lock:
            session = self._by_digest.get(_digest(token))
            if session is None:
                return None
            if now - session.last_seen > self.idle_limit_s:
                del self._by_digest[_digest(token)]
                return None
        if self.users is not None and self.users.current(session.user.name) != session.user:  # removed, or re-roled
            self.close_user(session.user.name)
            return None
        session.last_seen = now
        return session

    def close_user(self, name: str) -> int:
        """Log a user out everywhere; how many logins were closed."""
        with self._lock:
            gone = [d for d, s in self._by_digest.items() if s.user.name == name]
            for d in gone:
                del self._by_digest[d]
        return len(gone)

    def close(self, token: str | None) -> None:
        if token:
            with self._lock:
                self._by_digest.pop(_digest(token), None)


class LoginThrottle:
    """Failed logins per (user name, address) and per address in a sliding window; bounded memory
    (THROTTLE_KEYS)."""

    def __init__(
        self, max_failures: int = MAX_FAILURES, window_s: float = FAILURE_WINDOW_S, max_keys: int = THROTTLE_KEYS
    ) -> None:
        self.max_failures = max_failures
        self.window_s = window_s
        self.max_keys = max_keys
        self._failures: OrderedDict[str, list[float]] = OrderedDict()
        self._refusals: dict[str, int] = {}
        self._lock = threading.Lock()

    @staticmethod
    def keys(user: str, address: str | None) -> tuple[str, str]:
        """The counters a login attempt counts against: its name from its address, and its address."""
        where = address or "unknown"
        return f"user:{user}@{where}", f"addr:{where}"

    def _recent(self, key: str, now: float) -> list[float]:
        times = [t for t in self._failures.get(key, ()) if now - t < self.window_s]
        if times:
            self._failures[key] = times
        else:
            self._failures.pop(key, None)
            self._refusals.pop(key, None)
        return times

    def retry_after_s(self, user: str, address: str | None) -> float:
        """0 if a login may be tried; otherwise seconds until the oldest failure counted leaves the window."""
        now = host_clock().now_s()
        wait = 0.0
        with self._lock:
            for key in self.keys(user, address):
                times = self._recent(key, now)
                if len(times) >= self.max_failures:
                    wait = max(wait, times[-self.max_failures] + self.window_s - now)
        return wait

    def refused(self, user: str, address: str | None) -> bool:
        """Count a refusal; True for the first of a window (the one worth an audit entry)."""
        with self._lock:
            first = False
            for key in self.keys(user, address):
                n = self._refusals.get(key, 0)
                self._refusals[key] = n + 1
                first = first or n == 0
            return first

    def failed(self, user: str, address: str | None) -> None:
        now = host_clock().now_s()
        with self._lock:
            for key in self.keys(user, address):
                times = self._recent(key, now)
                self._failures[key] = [*times, now][-self.max_failures :]
                self._failures.move_to_end(key)
            while len(self._failures) > self.max_keys:
                old, _ = self._failures.popitem(last=False)
                self._refusals.pop(old, None)

    def succeeded(self, user: str, address: str | None) -> None:
        """A right password clears the name's failures from that address (not the address's: one address may try
        many names)."""
        key = self.keys(user, address)[0]
        with self._lock:
            self._failures.pop(key, None)
            self._refusals.pop(key, None)


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
GATES = (operator, viewer_action, viewer)  # strictest first


def gate_of(dependant: Dependant) -> Callable[..., object] | None:
    """The strictest of GATES among a route's dependencies (its own and theirs), None for an open route: what the
    panel checks before it reads a request body (web.app.AuthBeforeBody), from the route's own declaration."""
    calls: set[object] = set()
    todo = [dependant]
    while todo:
        d = todo.pop()
        calls.add(d.call)
        todo.extend(d.dependencies)
    return next((g for g in GATES if g in calls), None)


def admit(request: Request, gate: Callable[..., object]) -> None:
    """The route's gate applied to a request's cookie and CSRF header alone (HTTPException 401 or 403), with the
    very checks and messages its dependencies apply."""
    session = viewer(request, request.cookies.get(SESSION_COOKIE))
    if gate is not viewer:
        gate(session, request.headers.get(CSRF_HEADER))
