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


@router.post("/login", responses=errors(400, 401, 422))
def login(body: Login, request: Request, response: Response) -> Me:
    """Check the password (Argon2id hash in the users file) and open a login session (HttpOnly cookie)."""
    p = panel(request)
    user = UserBook(p.config.users).verify(body.username, body.password)
    if user is None:
        p.audit.record(body.username, "login", ok=False, client=request.client.host if request.client else None)
        raise HTTPException(401, "wrong user name or password")
    token, session = p.logins.open(user)
    response.set_cookie(SESSION_COOKIE, token, max_age=int(IDLE_LIMIT_S), httponly=True, samesite="strict",
                        secure=p.config.secure_cookies, path="/")  # fmt: skip
    p.audit.record(user.name, "login", ok=True, role=user.role, client=request.client.host if request.client else None)
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
