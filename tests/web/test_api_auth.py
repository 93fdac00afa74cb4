"""Login, logout, CSRF, roles, pages and assets of the panel."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from web.auth import SESSION_COOKIE


@pytest.fixture
def anonymous(app_client) -> TestClient:
    return TestClient(app_client.app, base_url="http://127.0.0.1")


def test_login_sets_a_strict_httponly_cookie_and_gives_the_csrf_token(anonymous, passwords):
    reply = anonymous.post("/api/login", json={"username": "olga", "password": passwords["olga"]})
    assert reply.status_code == 200
    body = reply.json()
    assert body["user"] == "olga" and body["role"] == "operator" and len(body["csrf"]) >= 32
    cookie = reply.headers["set-cookie"].lower()
    assert f"{SESSION_COOKIE}=" in cookie and "httponly" in cookie and "samesite=strict" in cookie
    assert anonymous.get("/api/me").json() == body


@pytest.mark.parametrize("username", ["olga", "nobody"])
def test_a_wrong_password_or_name_is_401_and_audited(anonymous, panel_config, username):
    reply = anonymous.post("/api/login", json={"username": username, "password": "wrong-password"})
    assert reply.status_code == 401
    assert reply.json()["detail"] == "wrong user name or password"
    assert SESSION_COOKIE not in anonymous.cookies
    last = json.loads(panel_config.audit_log.read_text().splitlines()[-1])
    assert last["user"] == username and last["action"] == "login" and last["ok"] is False


def test_login_with_a_missing_field_is_422_naming_it(anonymous):
    reply = anonymous.post("/api/login", json={"username": "olga"})
    assert reply.status_code == 422
    assert reply.json()["detail"] == "body.password: Field required"


@pytest.mark.parametrize(("method", "path"), [("GET", "/api/me"), ("POST", "/api/logout")])
def test_me_and_logout_need_a_login(anonymous, method, path):
    reply = anonymous.request(method, path)
    assert reply.status_code == 401 and reply.json()["detail"] == "not logged in: POST /api/login first"


def test_logout_needs_the_csrf_token_then_ends_the_session(as_user):
    client = as_user("victor")
    token = client.headers.pop("X-CSRF-Token")
    refused = client.post("/api/logout")
    assert refused.status_code == 403 and "CSRF" in refused.json()["detail"]
    assert client.post("/api/logout", headers={"X-CSRF-Token": "forged"}).status_code == 403
    assert client.post("/api/logout", headers={"X-CSRF-Token": token}).status_code == 200
    assert client.get("/api/me").status_code == 401


def test_a_stolen_cookie_value_from_another_login_is_not_a_csrf_token(as_user):
    olga, victor = as_user("olga"), as_user("victor")
    olga.headers["X-CSRF-Token"] = victor.headers["X-CSRF-Token"]
    assert olga.post("/api/stations/sim/pause").status_code == 403


def test_passwords_are_stored_as_argon2id_hashes_only(panel_config, passwords):
    text = panel_config.users.read_text()
    assert all(p not in text for p in passwords.values())
    assert text.count("$argon2id$") == len(passwords)
    assert panel_config.users.stat().st_mode & 0o077 == 0


@pytest.mark.parametrize("path", ["/", "/history", "/gap", "/sessions/20260101T000000-abcdef12"])
def test_pages_send_anonymous_visitors_to_the_login_page(anonymous, path):
    reply = anonymous.get(path, follow_redirects=False)
    assert reply.status_code == 303 and reply.headers["location"] == "/login"


@pytest.mark.parametrize(
    ("path", "script"),
    [("/", "live"), ("/history", "history"), ("/gap", "gap"), ("/sessions/20260101T000000-abcdef12", "session")],
)
def test_pages_for_a_logged_in_user_load_only_the_panels_own_assets(app_client, log_in, path, script):
    log_in(app_client, "victor")
    reply = app_client.get(path)
    assert reply.status_code == 200
    assert f'src="/static/{script}.js"' in reply.text and "/vendor/uplot/uPlot.iife.min.js" in reply.text
    assert "http://" not in reply.text and "https://" not in reply.text
    assert "default-src 'self'" in reply.headers["content-security-policy"]


def test_the_login_page_is_public_and_a_bad_session_uid_is_422(anonymous):
    assert anonymous.get("/login").status_code == 200
    assert anonymous.get("/sessions/..%2Fetc").status_code in (404, 422)


@pytest.mark.parametrize(
    "path", ["/vendor/uplot/uPlot.iife.min.js", "/vendor/uplot/uPlot.min.css", "/static/common.js", "/static/panel.css"]
)
def test_assets_come_from_the_panel(anonymous, path):
    reply = anonymous.get(path)
    assert reply.status_code == 200 and len(reply.content) > 500


def test_no_interactive_docs_that_would_load_scripts_from_the_internet(anonymous):
    assert anonymous.get("/docs").status_code == 404
    assert anonymous.get("/openapi.json").status_code == 401  # the schema is for logged-in users only
