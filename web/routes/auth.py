"""Log in, log out, who am I."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, Response

from web.auth import IDLE_LIMIT_S, SESSION_COOKIE, LoginSession, Viewer, ViewerAction
from web.schemas import Login, Me, errors
from web.state import panel
from web.users import UserBook

router = APIRouter(prefix="/api", tags=["auth"])


def _me(session: LoginSession) -> Me:
    return Me(user=session.user.name, role=session.user.role, csrf=session.csrf)


@router.post("/login", responses=errors(400, 401, 422, 429))
def login(body: Login, request: Request, response: Response) -> Me:
    """Check the password (Argon2id hash in the users file) and open a login session (HttpOnly cookie)."""
    p = panel(request)
    client = request.client.host if request.client else None
    wait_s = p.throttle.retry_after_s(body.username, client)
    if wait_s > 0:  # refused before the password is checked: guessing costs the panel nothing
        if p.throttle.refused(body.username, client):
            p.audit.record(body.username, "login_throttled", ok=False, client=client, retry_after_s=round(wait_s))
        raise HTTPException(429, f"too many failed logins from this address (for this user, or for all): try again "
                            f"in {wait_s:.0f} s",
                            headers={"Retry-After": str(max(1, round(wait_s)))})  # fmt: skip
    user = UserBook(p.config.users).verify(body.username, body.password)
    if user is None:
        p.throttle.failed(body.username, client)
        p.audit.record(body.username, "login", ok=False, client=client)
        raise HTTPException(401, "wrong user name or password")
    p.throttle.succeeded(user.name, client)
    token, session = p.logins.open(user)
    response.set_cookie(SESSION_COOKIE, token, max_age=int(IDLE_LIMIT_S), httponly=True, samesite="strict",
                        secure=p.config.secure_cookies, path="/")  # fmt: skip
    p.audit.record(user.name, "login", ok=True, role=user.role, client=client)
    return _me(session)


@router.post("/logout", responses=errors(401, 403))
def logout(request: Request, response: Response, session: ViewerAction) -> dict:
    p = panel(request)
    p.logins.close(request.cookies.get(SESSION_COOKIE))
    response.delete_cookie(SESSION_COOKIE, path="/")
    p.audit.record(session.user.name, "logout")
    return {"ok": True}


@router.get("/me", responses=errors(401))
def me(session: Viewer) -> Me:
    """The logged-in user, role and CSRF token."""
    return _me(session)
