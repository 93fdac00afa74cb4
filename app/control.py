"""The station's control channel: a zmq REP socket in front of a StationController.

The web panel (another process, perhaps another machine) sends one request at a
time, as three frames, and gets one JSON reply (the contract and the panel's client:
station.control_channel):

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

import hmac
import json
import logging
import threading
from collections.abc import Callable
from typing import Any

import zmq

from app.controller import StationController
from devices.errors import DriverError
from engine.context import ValidationError
from engine.params import ParameterError
from engine.registry import ProcedureError
from station.clock import host_clock
from station.control_channel import (
    CONTROL_ACTIONS,
    DEFAULT_IDENTITY,
    MAX_DEPTH,
    MAX_REQUEST_BYTES,
    ControlError,
    nesting_depth,
    request_mac,
)
from station.jsonsafe import json_safe
from station.provenance import ProvenanceError
from station.store import StoreError

log = logging.getLogger(__name__)
REQUEST_ERRORS = (
    ControlError, ProcedureError, ParameterError, ValidationError, DriverError, StoreError, KeyError, TypeError,
    ProvenanceError,
)  # fmt: skip
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
        self._served = host_clock().event()
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
        if self._thread.is_alive():
            self._served.wait(timeout_s=2.0)
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
        try:
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
        finally:
            self._served.set()
