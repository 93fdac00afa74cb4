"""The station's control channel: a zmq REP socket in front of a StationController.

The web panel (another process, perhaps another machine) sends one request at a
time, as three frames, and gets one JSON reply:

    request  [identity, HMAC-SHA256(token, identity NUL body) in hex, body]
             body = {"cmd": ..., "args": {...}, "user": "for whom a delegate (the panel) asks"}
    reply    {"ok": true, "result": ...} | {"ok": false, "error": {"type": ..., "message": ...}}

Authenticated by default and before anything is parsed: the identity must be
one the station knows and the MAC must match (hmac.compare_digest) before the
body is even scanned; `station serve` creates its token on first start
(`ensure_token`, 256 random bits in a file only its owner may read, 0600)
unless one is given. Bounded and flat: zmq refuses a frame over
MAX_REQUEST_BYTES (ZMQ_MAXMSGSIZE), and a body nested deeper than MAX_DEPTH is
refused by a scan before json.loads (whose recursion a 100 kB `[[[[` once
turned into a RecursionError that killed this thread). Who acted is the
authenticated identity: the event log records `pause by panel` or, when the
panel relays a logged-in user, `pause by bob via panel`; a name in the message
alone is never trusted.

Commands: status, library, plan {procedure, params}, start {procedure, params,
instrument_serial}, resume_session {uid}, pause, resume, abort, estop,
acknowledge (the operator did what an OperatorAction step asked), reset (clear an
emergency stop or a drive fault once its cause is removed). `plan`
and `start` validate the parameters and every step before anything moves; a
bad request gets its validation message back unchanged (it names the field,
the value and what is allowed). Every control action goes to the session's
event log with who asked. This channel binds to localhost unless configured otherwise.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import os
import secrets
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zmq

from app.controller import ControlError, StationController
from devices.errors import DriverError
from engine.context import ValidationError
from engine.params import ParameterError
from engine.registry import ProcedureError
from station.jsonsafe import json_safe
from station.provenance import ProvenanceError
from station.store import StoreError

log = logging.getLogger(__name__)
REQUEST_ERRORS = (
    ControlError, ProcedureError, ParameterError, ValidationError, DriverError, StoreError, KeyError, TypeError,
    ProvenanceError,
)  # fmt: skip
CONTROL_ACTIONS = ("start", "resume_session", "pause", "resume", "abort", "estop", "acknowledge", "reset")
MAX_REQUEST_BYTES = 64 * 1024  # a start with a few hundred positions is under 10 kB
MAX_DEPTH = 5  # {"args": {"params": {"positions_deg": [...]}}} is 4 deep
DEFAULT_IDENTITY = "panel"
TOKEN_FILE = "control.token"


def ensure_token(path: str | Path) -> str:
    """The token in `path`, created on first use (256 random bits, hex) readable by its owner only (0600).

    A file that others may read or write is refused: its token can no longer be trusted."""
    path = Path(path)
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(secrets.token_hex(32) + "\n")
    mode = path.stat().st_mode & 0o777
    if mode & 0o077:
        raise ControlError(f"control token {path}: mode {mode:o} lets others read it; allowed 600 (chmod 600 {path})")
    token = path.read_text().strip()
    if len(token) < 32:
        raise ControlError(f"control token {path}: {len(token)} characters; allowed at least 32")
    return token


def request_mac(token: str, identity: bytes, body: bytes) -> bytes:
    """HMAC-SHA256 of identity NUL body under the token, hex: what authenticates a request."""
    return hmac.new(token.encode(), identity + b"\0" + body, hashlib.sha256).hexdigest().encode()


def nesting_depth(body: bytes, limit: int) -> int:
    """Bracket depth of a JSON text (strings skipped), scanning no further than a depth above limit."""
    depth = deepest = 0
    in_string = escaped = False
    for ch in body.decode("utf-8", errors="replace"):
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
            if deepest > limit:
                return deepest
        elif ch in "]}":
            depth -= 1
    return deepest


def _error(kind: str, message: str) -> dict:
    return {"ok": False, "error": {"type": kind, "message": message}}


class ControlServer:
    """Serves control requests for one controller in a background thread."""

    def __init__(
        self,
        controller: StationController,
        endpoint: str,
        *,
        token: str,
        identities: tuple[str, ...] = (DEFAULT_IDENTITY,),
        context: zmq.Context | None = None,
    ) -> None:
        if not token:
            raise ControlError("the control channel needs a token (ensure_token creates one)")
        self.controller = controller
        self._tokens = {name.encode(): token for name in identities}
        self._ctx = context or zmq.Context.instance()
        self._sock = self._ctx.socket(zmq.REP)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.MAXMSGSIZE, MAX_REQUEST_BYTES)
        self._sock.bind(endpoint)
        self.endpoint = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="control", daemon=True)
        self._handlers: dict[str, Callable[[dict], Any]] = {
            "status": lambda a: controller.status(),
            "library": lambda a: controller.library(),
            "plan": lambda a: controller.plan(a["procedure"], a.get("params", {}))[1].to_json(),
            "start": self._start,
            "resume_session": lambda a: {"session_uid": controller.resume_session(a["uid"])[0]},
            "pause": lambda a: controller.pause(),
            "resume": lambda a: controller.resume(),
            "abort": lambda a: controller.abort(),
            "acknowledge": lambda a: controller.engine.acknowledge(),
            "reset": lambda a: controller.reset(),
            "estop": lambda a: controller.emergency_stop(),
        }

    def start(self) -> ControlServer:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sock.close()

    def _start(self, a: dict) -> dict:
        uid, plan = self.controller.start(
            a["procedure"], a.get("params", {}), instrument_serial=str(a.get("instrument_serial", ""))
        )
        return {"session_uid": uid, "plan": plan.to_json()}

    def authenticate(self, frames: list[bytes]) -> tuple[str, bytes] | dict:
        """(identity, body) of an authentic request of bounded size; otherwise the error reply. Nothing is parsed."""
        if len(frames) != 3:
            return _error("Unauthorized", "bad or missing control token (expected identity, MAC and body frames)")
        identity, mac, body = frames
        token = self._tokens.get(identity)
        expected = request_mac(token, identity, body) if token is not None else b"0" * 64
        if not hmac.compare_digest(mac, expected) or token is None:
            return _error("Unauthorized", "bad or missing control token")
        if len(body) > MAX_REQUEST_BYTES:
            return _error("BadRequest", f"request of {len(body)} bytes; allowed at most {MAX_REQUEST_BYTES}")
        return identity.decode(), body

    def handle_frames(self, frames: list[bytes]) -> dict:
        """Authenticate, bound, parse and answer one request (the serving thread's whole work for it)."""
        auth = self.authenticate(frames)
        if isinstance(auth, dict):
            return auth
        identity, body = auth
        depth = nesting_depth(body, MAX_DEPTH)
        if depth > MAX_DEPTH:
            return _error("BadRequest", f"request nested {depth} deep or more; allowed at most {MAX_DEPTH}")
        try:
            request = json.loads(body)
        except ValueError:
            request = None
        if not isinstance(request, dict):
            return _error("BadRequest", "expected a JSON object")
        return self.handle(request, identity)

    def handle(self, request: dict, identity: str) -> dict:
        """One parsed request of an authenticated identity to its reply (public for tests and in-process use)."""
        cmd = request.get("cmd")
        handler = self._handlers.get(cmd) if isinstance(cmd, str) else None
        if handler is None:
            allowed = ", ".join(self._handlers)
            return {"ok": False, "error": {"type": "UnknownCommand", "message": f"cmd = {cmd!r}; allowed: {allowed}"}}
        args = request.get("args") or {}
        if not isinstance(args, dict):
            return {"ok": False, "error": {"type": "BadRequest", "message": f"args = {args!r}: expected an object"}}
        if cmd == "start":  # the session's provenance names who started it: the panel's user, else the OS user
            self.controller.engine.operator = str(request.get("user") or "")[:64] or None
        try:
            result = handler(args)
        except REQUEST_ERRORS as exc:
            return {"ok": False, "error": {"type": type(exc).__name__, "message": str(exc)}}
        except Exception as exc:  # the channel outlives any request: an unexpected error is a reply, not a dead thread
            log.exception("control request %r failed", cmd)
            return {"ok": False, "error": {"type": "InternalError", "message": f"{type(exc).__name__}: {exc}"}}
        if cmd in CONTROL_ACTIONS:
            user = str(request.get("user") or "")[:64]
            self._log(cmd, f"{user} via {identity}" if user and user != identity else identity, args)
        return {"ok": True, "result": result}

    def _log(self, cmd: str, who: str, args: dict) -> None:
        uid = self.controller.engine.progress.session_uid
        if uid:
            try:
                self.controller.store.add_event(uid, "control", f"{cmd} by {who}" + (f" {args}" if args else ""))
            except Exception as exc:  # the action was done; a store that cannot take its record must not undo it
                log.error("control %s by %s not recorded: %s", cmd, who, exc)

    def _serve(self) -> None:
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        while not self._stop.is_set():
            if not poller.poll(100):
                continue
            frames = self._sock.recv_multipart()
            try:
                reply = self.handle_frames(frames)
            except Exception as exc:  # the channel outlives any request
                log.exception("control request failed")
                reply = _error("InternalError", f"{type(exc).__name__}: {exc}")
            self._sock.send(json.dumps(json_safe(reply)).encode())


class ControlClient:
    """The panel's side: one request at a time, a bounded wait for the reply."""

    def __init__(
        self, endpoint: str, *, token: str | None, identity: str = DEFAULT_IDENTITY, timeout_s: float = 10.0
    ) -> None:
        self.endpoint = endpoint
        self._token = token or ""
        self._identity = identity.encode()
        self._timeout_ms = round(timeout_s * 1000)
        self._ctx = zmq.Context.instance()
        self._lock = threading.Lock()
        self._sock = self._new_socket()

    def _new_socket(self) -> zmq.Socket:
        sock = self._ctx.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVTIMEO, self._timeout_ms)
        sock.setsockopt(zmq.SNDTIMEO, self._timeout_ms)
        sock.connect(self.endpoint)
        return sock

    def request(self, cmd: str, args: dict | None = None, user: str = "") -> dict:
        """The reply document; {"ok": false, "error": {"type": "Timeout"}} if the station does not answer."""
        body = json.dumps({"cmd": cmd, "args": args or {}, "user": user}).encode()
        frames = [self._identity, request_mac(self._token, self._identity, body), body]
        with self._lock:
            try:
                self._sock.send_multipart(frames)
                return json.loads(self._sock.recv())
            except zmq.Again:
                self._sock.close()  # a REQ socket that missed its reply cannot send again
                self._sock = self._new_socket()
                return {"ok": False, "error": {"type": "Timeout", "message": f"no reply from {self.endpoint}"}}

    def close(self) -> None:
        with self._lock:
            self._sock.close()
