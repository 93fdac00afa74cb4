"""Authentication before the body: `station panel` (its own process, bench/fuzz_panel.PanelProcess) answers a
request whose login, role or CSRF token its route refuses with 401 or 403 before it reads the body (FastAPI used
to read, and spool to disk, a whole multipart upload of up to 257 MiB before the route's login check ran).

Measured over real TCP with a client that streams 200 MiB in 1 MiB chunks and looks for an answer before each:
how much it had sent when the answer came, how long that took, and the panel's RSS before and after.
Tolerances: the answer must come before ANSWERED_BY of the 200 MiB are sent (loopback socket buffers hold a few
MiB before the panel's first read; the old panel answered after all 200) and within ANSWER_S (a loaded 2-core
machine); the panel's RSS may grow by at most RSS_GROWTH (allocator noise; a body read into memory is 200 MiB).
"""

from __future__ import annotations

import json
import select
import socket
import time
from collections.abc import Iterator

import pytest

from bench.fuzz_panel import BOUNDARY, MiB, PanelProcess, exchange, multipart, request_head
from web.app import OPEN_BODY_BYTES
from web.auth import CSRF_HEADER

pytestmark = pytest.mark.timeout(180)
STREAMED = 200 * MiB
ANSWERED_BY = 32 * MiB
ANSWER_S = 5.0
RSS_GROWTH = 16 * MiB


@pytest.fixture(scope="module")
def panel(tmp_path_factory) -> Iterator[PanelProcess]:
    with PanelProcess(tmp_path_factory.mktemp("auth-before-body") / "run") as p:
        yield p
        time.sleep(0.3)
        assert p.tracebacks() == 0, p.log.read_text(errors="replace")[-4000:]


def stream(port: int, path: str, headers: list[tuple[str, str]], total: int = STREAMED) -> tuple[int, int, float]:
    """Stream a chunked multipart body of `total` bytes until an answer comes; (status, bytes sent by then,
    seconds from the request's head to the answer)."""
    head = request_head("POST", path, [*headers, ("Content-Type", f"multipart/form-data; boundary={BOUNDARY}"),
                                       ("Transfer-Encoding", "chunked")])  # fmt: skip
    part = multipart(b"")[: -len(f"\r\n--{BOUNDARY}--\r\n")]  # a file field's head: then its content streams
    chunk = b"%x\r\n" % MiB + bytes(MiB) + b"\r\n"
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        t0 = time.monotonic()
        s.sendall(head + b"%x\r\n" % len(part) + part + b"\r\n")
        sent = 0
        while sent < total and not select.select([s], [], [], 0)[0]:
            s.sendall(chunk)
            sent += MiB
        if sent >= total:
            s.sendall(b"0\r\n\r\n")
        reply = s.recv(65536)
        seconds = time.monotonic() - t0
        while b"\r\n\r\n" not in reply and (more := s.recv(65536)):
            reply += more
    assert reply.startswith(b"HTTP/1.1 "), reply[:200]
    return int(reply.split(b" ", 2)[1]), sent, seconds


def _as(panel: PanelProcess, who: str, csrf: bool = True) -> list[tuple[str, str]]:
    cookie, token = panel.cookies[who]
    return [("Cookie", cookie)] + ([(CSRF_HEADER, token)] if csrf else [])


@pytest.mark.parametrize(
    ("who", "csrf", "path", "status"),
    [
        (None, False, "/api/gap", 401),  # anonymous upload
        ("victor", False, "/api/gap", 403),  # logged in, no CSRF token
        ("victor", True, "/api/stations/sim/start", 403),  # a viewer's body to an operator's route
        (None, False, "/api/stations/sim/start", 401),
    ],
    ids=["anonymous-upload", "upload-without-csrf", "viewer-to-operator-route", "anonymous-start"],
)
def test_a_refused_request_is_answered_before_its_body_is_read(panel, who, csrf, path, status) -> None:
    rss0 = panel.rss_bytes()
    headers = [] if who is None else _as(panel, who, csrf)
    got, sent, seconds = stream(panel.port, path, headers)
    growth = panel.rss_bytes() - rss0
    print(f"{path} as {who or 'anonymous'}: {got} after {sent / MiB:.0f} MiB sent, {seconds * 1e3:.0f} ms; "
          f"RSS {growth / MiB:+.1f} MiB")  # fmt: skip
    assert got == status
    assert sent < ANSWERED_BY, f"answered after {sent / MiB:.0f} MiB of {STREAMED / MiB:.0f}; allowed below 32"
    assert seconds < ANSWER_S
    assert growth < RSS_GROWTH, f"RSS grew {growth / MiB:.1f} MiB; allowed {RSS_GROWTH / MiB:.0f}"
    assert panel.leftovers() == []  # nothing spooled to the panel's TMPDIR


def test_a_body_to_the_open_login_route_is_bounded(panel) -> None:
    big = json.dumps({"username": "olga", "password": "x" * OPEN_BODY_BYTES}).encode()
    head = request_head("POST", "/api/login", [("Content-Type", "application/json"), ("Content-Length", str(len(big)))])
    reply, _ = exchange(panel.port, head, [big])
    assert reply[0] == ("status", "413")
    ok = json.dumps({"username": "olga", "password": "operator-pass-1"}).encode()
    head = request_head("POST", "/api/login", [("Content-Type", "application/json"), ("Content-Length", str(len(ok)))])
    assert exchange(panel.port, head, [ok])[0][0] == ("status", "200")  # a login is still a login


def test_an_authorised_upload_still_reaches_its_route(panel) -> None:
    """The gate lets an operator's upload with its CSRF token through to the route (which refuses a non-zip)."""
    body = multipart(b"not a zip")
    kind = ("Content-Type", f"multipart/form-data; boundary={BOUNDARY}")
    head = request_head("POST", "/api/gap", [*_as(panel, "olga"), ("Content-Length", str(len(body))), kind])
    reply, text = exchange(panel.port, head, [body])
    assert reply[0] == ("status", "422"), text


def test_every_route_that_takes_a_body_is_gated_but_the_login() -> None:
    """The gate is read from each route's own dependencies (web.auth.gate_of): a new route that changes something
    without a login shows here."""
    from fastapi import FastAPI

    from web.app import api_routes
    from web.auth import gate_of, operator
    from web.routes import auth, control, gap, history, live, pages

    app = FastAPI()
    for module in (auth, live, control, history, gap, pages):
        app.include_router(module.router)
    writes = [r for r in api_routes(app.router.routes) if r.methods & {"POST", "PUT", "PATCH", "DELETE"}]
    assert [r.path for r in writes if gate_of(r.dependant) is None] == ["/api/login"]
    assert {r.path for r in writes if gate_of(r.dependant) is operator} >= {"/api/stations/{name}/start"}
