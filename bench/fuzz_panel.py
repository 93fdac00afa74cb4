"""Fuzz the panel as a remote attacker or a careless user would (issue 30, deliverable 7): requests and uploads.

`station panel` runs as an operator starts it (its own process, its log on stderr written to a file) in front of
a placeholder station (nothing serves its control channel) and a session store with one stored session. Each
case is one request over a raw TCP connection, so that anything goes: made-up and mangled zip uploads (random
bytes, random members and member names, a lawful session's archive with bytes flipped, cut short or a member
replaced), broken multipart framing, chunked or Content-Length bodies, bodies over the bound (MAX_BODY_BYTES,
declared or streamed), clients that give up half-way through a body, every route with made-up path parameters,
queries, X-Forwarded-For and bodies, anonymous, viewer or operator, with or without the CSRF token.

What counts, per case and in all: a 5xx answer (none allowed: the placeholder station is never asked, its
routes are fuzzed with other station names), a traceback in the panel's log (none allowed), a body over the bound
that is not refused with 413, a refusal that changed the store or left temporary files, and the panel's peak RSS.
The suite's tests/web/test_fuzz_panel.py runs the same cases briefly with a fixed seed; this is the long run:

    PYTHONPATH=. .venv/bin/python bench/fuzz_panel.py [--examples 3000] [--seed 30] [--oversized 20]

Simulation path: the stored session is the session_sim shortcut (not the engine): station.twin.session_sim, data to
serve.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import platform
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st

from web.app import MAX_BODY_BYTES

MiB = 1 << 20
PASSWORDS = {"olga": "operator-pass-1", "victor": "viewer-pass-1"}
ROLES = {"olga": "operator", "victor": "viewer"}
START_S = 30.0  # the panel imports FastAPI, numpy and the twin: a few seconds on a loaded 2-core machine
REPLY_S = 60.0  # a lawful upload is diagnosed against the twin before the answer (a few seconds)
BOUNDARY = "fuzzboundary"
TRACEBACK = "Traceback (most recent call last)"
CONTINUE = b"HTTP/1.1 100 "
# A client that sends Expect: 100-continue waits this long for the interim answer (or a final one) before its body
# (RFC 9110 10.1.1): sent at once, a large body met the panel's early answer and close as a reset, and the answer
# was lost to the client (an "unanswered" request on a loaded machine).
EXPECT_WAIT_S = 1.0
UID = "20260101T000000-abcdef12"
ROUTES = (  # every route of the panel; {} is a fuzzed path parameter
    ("GET", "/login"), ("GET", "/"), ("GET", "/history"), ("GET", "/sessions/{}"), ("GET", "/gap"),
    ("POST", "/api/login"), ("POST", "/api/logout"), ("GET", "/api/me"), ("GET", "/api/sessions"),
    ("GET", "/api/sessions/{}"), ("GET", "/api/sessions/{}/residuals"), ("GET", "/api/sessions/{}/report"),
    ("GET", "/api/sessions/{}/certificate"), ("GET", "/api/sessions/{}/certificate.pdf"),
    ("GET", "/api/sessions/{}/export"), ("GET", "/api/sessions/{}/gap"), ("POST", "/api/gap"),
    ("GET", "/api/gap/{}"), ("GET", "/api/gap/{}/report"), ("GET", "/api/stations"), ("GET", "/api/relay"),
    ("GET", "/api/stations/{}/status"), ("GET", "/api/stations/{}/library"), ("POST", "/api/stations/{}/plan"),
    ("POST", "/api/stations/{}/start"), ("POST", "/api/stations/{}/resume-session"), ("GET", "/api/audit"),
    ("GET", "/openapi.json"), ("GET", "/static/common.js"), ("GET", "/vendor/uplot/uPlot.min.css"),
)  # fmt: skip
METHODS = ("GET", "POST", "PUT", "DELETE", "PATCH", "HEAD", "OPTIONS")


@dataclass(frozen=True)
class Case:
    """One request: what is sent, by whom, and how."""

    method: str
    path: str
    who: str | None  # None: anonymous
    csrf: bool
    body: bytes
    content_type: str
    chunked: bool
    extra_headers: tuple[tuple[str, str], ...] = ()
    oversized: int = 0  # bytes of filler streamed after `body` (a body over the bound)
    abort_after: int | None = None  # bytes of body sent before the client gives up


@dataclass
class Outcome:
    status: int | None  # None: the connection closed without an answer
    seconds: float


@dataclass
class Tally:
    """The campaign's counts."""

    requests: int = 0
    statuses: Counter = field(default_factory=Counter)
    server_errors: list[str] = field(default_factory=list)  # 5xx: method path status
    oversized_not_413: list[str] = field(default_factory=list)
    unanswered: list[str] = field(default_factory=list)  # no answer although the client sent its whole request
    store_changed: int = 0
    leftovers: int = 0
    tracebacks: int = 0
    peak_rss_bytes: int = 0


# ---- the panel under test ------------------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def lawful_archive() -> bytes:
    """A small lawful piga-session/1 session, zipped as the panel's upload takes it (raw streams included)."""
    from station.interchange import write_session
    from station.twin.config import TwinConfig
    from station.twin.plan import multiposition_plan
    from station.twin.session_sim import simulate_session

    session = simulate_session(multiposition_plan([0.0], [10.0], window_s=2.0), TwinConfig(), seed=3, raw=True)
    with tempfile.TemporaryDirectory() as tmp:
        d = write_session(session, Path(tmp) / "s")
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
            for path in sorted(d.rglob("*")):
                zf.write(path, f"s/{path.relative_to(d)}")
    return buf.getvalue()


class PanelProcess:
    """`station panel` in its own process over a fresh directory; its log, store, temporary files and RSS."""

    def __init__(self, root: Path, log_level: str = "warning") -> None:
        from station.store import SessionStore
        from station.twin.config import default_twin
        from station.twin.plan import seed000_plan
        from station.twin.session_sim import simulate_session
        from web.users import UserBook

        self.root = root
        self.log_level = log_level  # `station panel`'s default: warning (info adds uvicorn's access log)
        self.tmp = root / "tmp"  # the panel's TMPDIR: upload work directories must not outlive their request
        self.tmp.mkdir(parents=True)
        book = UserBook(root / "users.json")
        for name, password in PASSWORDS.items():
            book.add(name, ROLES[name], password)
        self.store = root / "station" / "station.sqlite"
        self.store.parent.mkdir()
        session = simulate_session(seed000_plan(), default_twin(), 5, raw=False, notes="fuzz")
        with SessionStore(self.store) as store:
            uid = store.create_session(session.station, "integral_precession", config={"params": {}})
            for p in session.points:
                store.add_point(uid, p)
            store.set_status(uid, "finished")
        self.uid = uid
        self.port = free_port()
        self.config = root / "panel.toml"
        self.config.write_text(
            f'[panel]\nusers = "{root / "users.json"}"\naudit_log = "{root / "audit.jsonl"}"\n'
            f'[[stations]]\nname = "sim"\ncontrol = "tcp://127.0.0.1:1"\ntelemetry = "tcp://127.0.0.1:1"\n'
            f'store = "{self.store}"\nreports = "{self.store.parent}"\n'
        )
        self.log = root / "panel.log"
        self.proc: subprocess.Popen | None = None
        self.cookies: dict[str, tuple[str, str]] = {}

    def __enter__(self) -> PanelProcess:
        env = os.environ | {"TMPDIR": str(self.tmp), "PYTHONUNBUFFERED": "1"}
        with self.log.open("w") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "station.cli.cli", "panel", "--config", str(self.config), "--port",
                str(self.port),
                 "--log-level", self.log_level],
                stdout=log, stderr=subprocess.STDOUT, env=env,
            )  # fmt: skip
        deadline = time.monotonic() + START_S
        while True:
            try:
                if send(self.port, Case("GET", "/login", None, False, b"", "", False)).status == 200:
                    break
            except OSError:
                pass
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.__exit__()
                raise RuntimeError(f"station panel did not start: {self.log.read_text()[-2000:]}")
            time.sleep(0.2)
        for name in PASSWORDS:
            self.cookies[name] = self._login(name)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def _login(self, name: str) -> tuple[str, str]:
        body = json.dumps({"username": name, "password": PASSWORDS[name]}).encode()
        head, reply = exchange(self.port, request_head("POST", "/api/login", [("Content-Type", "application/json"),
                                                                              ("Content-Length", str(len(body)))]),
                               [body])  # fmt: skip
        cookie = next(v for k, v in head if k == "set-cookie").split(";")[0]
        return cookie, json.loads(reply)["csrf"]

    def tracebacks(self) -> int:
        return self.log.read_text(errors="replace").count(TRACEBACK)

    def rss_bytes(self) -> int:
        import psutil

        assert self.proc is not None
        return psutil.Process(self.proc.pid).memory_info().rss

    def store_digest(self) -> str:
        """The store's files (database, WAL) and the reports beside it, as bytes."""
        h = hashlib.sha256()
        for path in sorted(self.store.parent.rglob("*")):
            if path.is_file():
                h.update(path.name.encode() + path.read_bytes())
        return h.hexdigest()

    def leftovers(self) -> list[Path]:
        return sorted(self.tmp.iterdir())

    def send(self, case: Case) -> Outcome:
        headers = list(case.extra_headers)
        if case.who is not None:
            cookie, csrf = self.cookies[case.who]
            headers.append(("Cookie", cookie))
            if case.csrf:
                headers.append(("X-CSRF-Token", csrf))
        return send(self.port, case, headers)


# ---- one request over a raw connection ------------------------------------------------------------------------


def request_head(method: str, path: str, headers: list[tuple[str, str]]) -> bytes:
    lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1", *(f"{k}: {v}" for k, v in headers)]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


def _body_parts(case: Case) -> Iterator[bytes]:
    filler = bytes(MiB)
    yield case.body
    left = case.oversized
    while left > 0:
        yield filler[: min(left, MiB)]
        left -= MiB


def send(port: int, case: Case, headers: list[tuple[str, str]] | None = None) -> Outcome:
    """Send the case; its status (None if the panel closed without answering) and how long it took."""
    headers = list(headers or [])
    size = len(case.body) + case.oversized
    if case.content_type:
        headers.append(("Content-Type", case.content_type))
    if case.method not in ("GET", "HEAD", "OPTIONS") or size:
        headers.append(("Transfer-Encoding", "chunked") if case.chunked else ("Content-Length", str(size)))
    parts = _body_parts(case)
    if case.chunked:
        parts = _chunked(parts)
    t0 = time.monotonic()
    try:
        head, _ = exchange(port, request_head(case.method, case.path, headers), parts, case.abort_after)
    except (ConnectionError, TimeoutError):
        return Outcome(None, time.monotonic() - t0)
    status = int(head[0][1]) if head else None
    return Outcome(status, time.monotonic() - t0)


def _chunked(parts: Iterator[bytes]) -> Iterator[bytes]:
    for p in parts:
        if p:
            yield b"%x\r\n" % len(p) + p + b"\r\n"
    yield b"0\r\n\r\n"


def exchange(
    port: int, head: bytes, parts: Iterator[bytes] | list[bytes], abort_after: int | None = None
) -> tuple[list[tuple[str, str]], bytes]:
    """Send head and body parts, stopping early once the answer has come (as a careful client does) or after
    abort_after body bytes (a client that gives up); the answer's status line and headers (first entry
    ("status", code)) and body. An empty list if the connection ended without an answer."""
    head_only = head.startswith(b"HEAD ")
    expect = b"\r\nexpect: 100-continue\r\n" in head.lower()
    with socket.create_connection(("127.0.0.1", port), timeout=REPLY_S) as s:
        s.sendall(head)
        sent = 0
        for p in parts:
            if abort_after is not None and sent + len(p) > abort_after:
                s.sendall(p[: max(0, abort_after - sent)])
                return [], b""
            if select.select([s], [], [], EXPECT_WAIT_S if expect and sent == 0 else 0)[0]:
                peek = s.recv(65536, socket.MSG_PEEK)
                if not peek.startswith(CONTINUE):
                    return _read_reply(s, head_only)  # answered before the whole body was sent (a 413)
                if b"\r\n\r\n" in peek:
                    s.recv(peek.index(b"\r\n\r\n") + 4)  # the interim 100 Continue: go on
            s.sendall(p)
            sent += len(p)
        return _read_reply(s, head_only)


def _read_reply(s: socket.socket, head_only: bool = False) -> tuple[list[tuple[str, str]], bytes]:
    """The next answer (an interim 100 Continue skipped); head_only: the answer to a HEAD (no body)."""
    data = b""
    while True:
        while b"\r\n\r\n" not in data:
            chunk = s.recv(65536)
            if not chunk:
                return [], b""
            data += chunk
        if not data.startswith(CONTINUE):
            break
        data = data.split(b"\r\n\r\n", 1)[1]
    raw_head, body = data.split(b"\r\n\r\n", 1)
    lines = raw_head.decode("latin-1").split("\r\n")
    headers = [("status", lines[0].split(" ")[1])]
    headers += [(k.strip().lower(), v.strip()) for k, v in (line.split(":", 1) for line in lines[1:])]
    length = 0 if head_only else next((int(v) for k, v in headers if k == "content-length"), None)
    chunked = not head_only and any(k == "transfer-encoding" for k, _ in headers)
    while (length is not None and len(body) < length) or (chunked and not body.endswith(b"0\r\n\r\n")):
        chunk = s.recv(65536)
        if not chunk:
            break
        body += chunk
    if chunked:
        body = _unchunk(body)
    return headers, body


def _unchunk(data: bytes) -> bytes:
    out = b""
    while data:
        size_line, _, data = data.partition(b"\r\n")
        n = int(size_line.split(b";")[0] or b"0", 16)
        if n == 0:
            break
        out, data = out + data[:n], data[n + 2 :]
    return out


# ---- the cases ------------------------------------------------------------------------------------------------

MEMBER_NAMES = ("s/session.json", "s/points.csv", "s/raw.h5", "s/raw/p.npz", "s/results.json", "session.json",
                "s/a.zip", "../escape", "/abs/path", "s/events.jsonl", "s/", "s/raw/p0001.npz")  # fmt: skip


def _flipped(data: bytes, flips: list[tuple[int, int]]) -> bytes:
    out = bytearray(data)
    for pos, value in flips:
        out[pos % len(out)] = value
    return bytes(out)


def _zip(members: list[tuple[str, bytes]], stored: bool) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED) as zf:
        for name, data in members:
            try:
                zf.writestr(name, data)
            except (IndexError, ValueError):  # a name zipfile cannot write ("/", "..", NUL): left out
                continue
    return buf.getvalue()


def _replace_member(lawful: bytes, index: int, data: bytes) -> bytes:
    with zipfile.ZipFile(io.BytesIO(lawful)) as zf:
        members = [(i.filename, zf.read(i)) for i in zf.infolist()]
    name, _ = members[index % len(members)]
    members[index % len(members)] = (name, data)
    return _zip(members, stored=False)


def archives(lawful: bytes) -> st.SearchStrategy[bytes]:
    """Uploads: random bytes, random zips, and a lawful session's archive mangled."""
    junk = st.binary(max_size=2048)
    members = st.lists(st.tuples(st.one_of(st.sampled_from(MEMBER_NAMES), st.text(min_size=1, max_size=30)),
                                 st.one_of(junk, st.just(b"{}"), st.just(lawful))), max_size=5)  # fmt: skip
    flips = st.lists(st.tuples(st.integers(0, len(lawful) - 1), st.integers(0, 255)), min_size=1, max_size=8)
    return st.one_of(
        junk,
        st.builds(lambda m, stored: _zip([(n[:200] or "x", d) for n, d in m], stored), members, st.booleans()),
        st.builds(lambda f: _flipped(lawful, f), flips),
        st.builds(lambda n: lawful[:n], st.integers(0, len(lawful) - 1)),
        st.builds(lambda i, d: _replace_member(lawful, i, d), st.integers(0, 50), junk),
    )


def multipart(archive: bytes, field_name: str = "archive", filename: str = "s.zip") -> bytes:
    head = (f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="{field_name}"; filename="{filename}"\r\n'
            "Content-Type: application/zip\r\n\r\n")  # fmt: skip
    return head.encode() + archive + f"\r\n--{BOUNDARY}--\r\n".encode()


who = st.sampled_from([None, "victor", "olga"])
csrf = st.sampled_from([True, True, True, False])  # mostly with the token: past the login checks
header = st.one_of(
    st.tuples(st.just("X-Forwarded-For"), st.sampled_from(["10.0.0.7", "203.0.113.9, 10.0.0.1", "<script>", "", "::1",
                                                          "1.2.3.4:5"])),
    st.sampled_from([("Expect", "100-continue"), ("Connection", "close"), ("X-Forwarded-Proto", "https"),
                     ("Content-Encoding", "gzip"), ("Accept", "text/html")]),
)  # fmt: skip
forwarded = st.lists(header, max_size=3).map(tuple)


@st.composite
def upload_cases(draw: st.DrawFn, lawful: bytes) -> Case:
    archive = draw(archives(lawful))
    framing = draw(st.sampled_from(["good", "good", "good", "field", "boundary", "cut", "raw"]))
    body = {
        "good": lambda: multipart(archive),
        "field": lambda: multipart(archive, field_name=draw(st.text(max_size=10).map(quote))),
        "boundary": lambda: multipart(archive).replace(BOUNDARY.encode(), b"other", 1),
        "cut": lambda: multipart(archive)[: draw(st.integers(0, len(archive) + 100))],
        "raw": lambda: archive,
    }[framing]()
    ctype = draw(st.sampled_from([f"multipart/form-data; boundary={BOUNDARY}"] * 4 + ["application/zip", "",
                                  "multipart/form-data", "application/json"]))  # fmt: skip
    return Case("POST", "/api/gap", draw(who), draw(csrf), body, ctype,
                draw(st.booleans()), draw(forwarded))  # fmt: skip


param = st.one_of(st.just(UID), st.sampled_from(["session-x", "upload-1", "sim2", "..", "%2e%2e%2f", "a" * 300]),
                  st.text(max_size=40).map(lambda t: quote(t, safe="")))  # fmt: skip
json_bodies = st.recursive(st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=20),
                           lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=10), c, max_size=4),
                           max_leaves=12).map(lambda v: json.dumps(v).encode())  # fmt: skip


@st.composite
def route_cases(draw: st.DrawFn) -> Case:
    method, template = draw(st.sampled_from(ROUTES))
    path = template.replace("{}", draw(param.filter(lambda p: p != "sim")), 1)  # the placeholder station: not asked
    if draw(st.booleans()):
        made_up = quote(draw(st.text(max_size=20)), safe="=&")
        path += "?" + draw(st.sampled_from(["limit=0", "limit=-1", "limit=99999999999999999999", "n=x", "a=%ff",
                                            "limit=1&limit=2", made_up]))  # fmt: skip
    if draw(st.integers(0, 9)) == 0:
        method = draw(st.sampled_from(METHODS))
    body = draw(st.one_of(st.just(b""), json_bodies, st.binary(max_size=512)))
    ctype = draw(st.sampled_from(["application/json", "", "text/plain", f"multipart/form-data; boundary={BOUNDARY}"]))
    return Case(method, path, draw(who), draw(csrf), body, ctype, draw(st.booleans()), draw(forwarded))


@st.composite
def aborted_cases(draw: st.DrawFn, lawful: bytes) -> Case:
    """A client that gives up part-way through its body."""
    case = draw(upload_cases(lawful))
    return Case(case.method, case.path, case.who, True, multipart(lawful), f"multipart/form-data; boundary={BOUNDARY}",
                case.chunked, abort_after=draw(st.integers(0, len(lawful))))  # fmt: skip


def cases(lawful: bytes) -> st.SearchStrategy[Case]:
    return st.one_of(upload_cases(lawful), route_cases(), aborted_cases(lawful))


def oversized_case(chunked: bool, who_: str | None, extra: int, headers: tuple[tuple[str, str], ...] = ()) -> Case:
    """A body just over the bound (MAX_BODY_BYTES + extra), declared by Content-Length or streamed chunked."""
    head = multipart(b"")[: -len(f"\r\n--{BOUNDARY}--\r\n")]
    return Case("POST", "/api/gap", who_, True, head, f"multipart/form-data; boundary={BOUNDARY}", chunked, headers,
                oversized=MAX_BODY_BYTES - len(head) + extra)  # fmt: skip


OVERSIZED_HEADERS = ((), (("Expect", "100-continue"),), (("Connection", "close"),))


# ---- checking one case ----------------------------------------------------------------------------------------


def check(panel: PanelProcess, case: Case, tally: Tally, digest: str) -> Outcome:
    """Send one case and count what it did: status, 5xx, oversized not 413, store or temporary files changed."""
    outcome = panel.send(case)
    tally.requests += 1
    tally.statuses[outcome.status] += 1
    how = f"{'chunked' if case.chunked else 'length'}, {case.who or 'anonymous'}, {dict(case.extra_headers)}"
    label = (
        f"{case.method} {case.path[:80]} ({how}{f', +{case.oversized} B' if case.oversized else ''}) -> "
        f"{outcome.status} in {outcome.seconds:.2f} s"
    )
    if outcome.status is not None and outcome.status >= 500:
        tally.server_errors.append(label)
    if outcome.status is None and case.abort_after is None:
        tally.unanswered.append(label)
    if case.oversized and outcome.status != (413 if case.who is not None else 401):  # anonymous: 401, body unread
        tally.oversized_not_413.append(label)
    if (outcome.status or 0) >= 400 and panel.store_digest() != digest:
        tally.store_changed += 1
    deadline = time.monotonic() + 5.0  # a dropped connection's request may still be finishing in the panel
    while panel.leftovers() and time.monotonic() < deadline:
        time.sleep(0.05)
    tally.leftovers += len(panel.leftovers())
    return outcome


class RssSampler:
    """The panel's peak RSS, sampled every `every_s` in a thread."""

    def __init__(self, panel: PanelProcess, every_s: float = 0.1) -> None:
        self.panel, self.every_s, self.peak = panel, every_s, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.peak = max(self.peak, self.panel.rss_bytes())
            except Exception:  # the process ended
                return
            self._stop.wait(self.every_s)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def campaign(root: Path, examples: int, seed: int, oversized: int, log_level: str = "warning") -> Tally:
    """The long run: `examples` hypothesis cases (seeded), then `oversized` bodies over the bound."""
    lawful = lawful_archive()
    tally = Tally()
    with PanelProcess(root, log_level) as panel, RssSampler(panel) as rss:
        digest = panel.store_digest()

        @hypothesis_seed(seed)
        @settings(max_examples=examples, deadline=None, database=None, phases=[Phase.generate],
                  suppress_health_check=list(HealthCheck))  # fmt: skip
        @given(cases(lawful))
        def run(case: Case) -> None:
            check(panel, case, tally, digest)

        run()
        for i in range(oversized):
            headers = OVERSIZED_HEADERS[(i // 2) % len(OVERSIZED_HEADERS)]
            check(panel, oversized_case(i % 2 == 1, (None, "victor", "olga")[i % 3], 1 + 4096 * i, headers), tally,
                  digest)  # fmt: skip
        time.sleep(0.5)
        tally.tracebacks = panel.tracebacks()
        tally.peak_rss_bytes = rss.peak

    return tally


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--examples", type=int, default=3000, help="fuzzed requests (default 3000)")
    ap.add_argument("--seed", type=int, default=30, help="hypothesis seed (default 30)")
    ap.add_argument("--oversized", type=int, default=20, help="bodies over the bound, half chunked (default 20)")
    ap.add_argument("--keep", help="directory to run in and keep (default: a temporary one)")
    ap.add_argument("--log-level", default="warning", choices=("warning", "info"),
                    help="the panel's (info: uvicorn's access log too, to find a traceback's request)")  # fmt: skip
    args = ap.parse_args()

    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="fuzz-panel-") as tmp:
        root = Path(args.keep or tmp)
        tally = campaign(root / "run", args.examples, args.seed, args.oversized, args.log_level)
    wall = time.monotonic() - t0
    print(f"fuzz_panel: {platform.node()}, {os.cpu_count()} CPUs, seed {args.seed}, {wall:.0f} s")
    print(f"requests {tally.requests}; statuses {dict(sorted(tally.statuses.items(), key=str))}")
    print(f"5xx {len(tally.server_errors)}; tracebacks in the panel's log {tally.tracebacks}; oversized not 413 "
          f"{len(tally.oversized_not_413)} of {args.oversized}; store changed on refusal {tally.store_changed}; "
          f"temporary files left {tally.leftovers}; unanswered {len(tally.unanswered)}; "
          f"peak RSS {tally.peak_rss_bytes / MiB:.0f} MiB")  # fmt: skip
    for label in tally.server_errors[:20] + tally.oversized_not_413[:20] + tally.unanswered[:20]:
        print("  ", label)
    bad = tally.server_errors or tally.oversized_not_413 or tally.unanswered or tally.tracebacks or tally.store_changed
    bad = bad or tally.leftovers
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
