"""The station's control channel: a zmq REP socket in front of a StationController.

The web panel (another process, perhaps another machine) sends one JSON
request at a time and gets one JSON reply:

    request  {"cmd": ..., "args": {...}, "user": "who asks", "token": "shared secret, if the server has one"}
    reply    {"ok": true, "result": ...} | {"ok": false, "error": {"type": ..., "message": ...}}

Commands: status, library, plan {procedure, params}, start {procedure, params,
instrument_serial}, resume_session {uid}, pause, resume, abort, estop,
acknowledge (the operator did what an OperatorAction step asked), reset (clear an
emergency stop or a drive fault once its cause is removed). `plan`
and `start` validate the parameters and every step before anything moves; a
bad request gets its validation message back unchanged (it names the field,
the value and what is allowed). Every control action goes to the session's
event log with who asked. Authentication of people is the panel's job; this
channel binds to localhost unless configured otherwise and can require a
shared token.
"""

from __future__ import annotations

import hmac
import json
import logging
import threading
from collections.abc import Callable
from typing import Any

import zmq

from app.controller import ControlError, StationController
from devices.errors import DriverError
from engine.context import ValidationError
from engine.params import ParameterError
from engine.registry import ProcedureError
from station.jsonsafe import json_safe
from station.store import StoreError

log = logging.getLogger(__name__)
REQUEST_ERRORS = (
    ControlError, ProcedureError, ParameterError, ValidationError, DriverError, StoreError, KeyError, TypeError,
)  # fmt: skip
CONTROL_ACTIONS = ("start", "resume_session", "pause", "resume", "abort", "estop", "acknowledge", "reset")


class ControlServer:
    """Serves control requests for one controller in a background thread."""

    def __init__(
        self,
        controller: StationController,
        endpoint: str,
        *,
        token: str | None = None,
        context: zmq.Context | None = None,
    ) -> None:
        self.controller = controller
        self._token = token
        self._ctx = context or zmq.Context.instance()
        self._sock = self._ctx.socket(zmq.REP)
        self._sock.setsockopt(zmq.LINGER, 0)
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

    def handle(self, request: dict) -> dict:
        """One request to its reply (public for tests and for an in-process panel)."""
        if self._token is not None and not hmac.compare_digest(str(request.get("token", "")), self._token):
            return {"ok": False, "error": {"type": "Unauthorized", "message": "bad or missing control token"}}
        cmd = request.get("cmd")
        handler = self._handlers.get(cmd) if isinstance(cmd, str) else None
        if handler is None:
            allowed = ", ".join(self._handlers)
            return {"ok": False, "error": {"type": "UnknownCommand", "message": f"cmd = {cmd!r}; allowed: {allowed}"}}
        args = request.get("args") or {}
        if not isinstance(args, dict):
            return {"ok": False, "error": {"type": "BadRequest", "message": f"args = {args!r}: expected an object"}}
        try:
            result = handler(args)
        except REQUEST_ERRORS as exc:
            return {"ok": False, "error": {"type": type(exc).__name__, "message": str(exc)}}
        except Exception as exc:  # the channel outlives any request: an unexpected error is a reply, not a dead thread
            log.exception("control request %r failed", cmd)
            return {"ok": False, "error": {"type": "InternalError", "message": f"{type(exc).__name__}: {exc}"}}
        if cmd in CONTROL_ACTIONS:
            self._log(cmd, str(request.get("user", "unknown")), args)
        return {"ok": True, "result": result}

    def _log(self, cmd: str, user: str, args: dict) -> None:
        uid = self.controller.engine.progress.session_uid
        if uid:
            self.controller.store.add_event(uid, "control", f"{cmd} by {user}" + (f" {args}" if args else ""))

    def _serve(self) -> None:
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        while not self._stop.is_set():
            if not poller.poll(100):
                continue
            raw = self._sock.recv()
            try:
                request = json.loads(raw)
                reply = self.handle(request) if isinstance(request, dict) else None
            except ValueError:
                reply = None
            if reply is None:
                reply = {"ok": False, "error": {"type": "BadRequest", "message": "expected a JSON object"}}
            self._sock.send(json.dumps(json_safe(reply)).encode())


class ControlClient:
    """The panel's side: one request at a time, a bounded wait for the reply."""

    def __init__(self, endpoint: str, *, token: str | None = None, timeout_s: float = 10.0) -> None:
        self.endpoint = endpoint
        self._token = token
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
        doc = {"cmd": cmd, "args": args or {}, "user": user}
        if self._token is not None:
            doc["token"] = self._token
        with self._lock:
            try:
                self._sock.send(json.dumps(doc).encode())
                return json.loads(self._sock.recv())
            except zmq.Again:
                self._sock.close()  # a REQ socket that missed its reply cannot send again
                self._sock = self._new_socket()
                return {"ok": False, "error": {"type": "Timeout", "message": f"no reply from {self.endpoint}"}}

    def close(self) -> None:
        with self._lock:
            self._sock.close()
