"""The station's control channel: a zmq ROUTER socket in front of a StationController.

The web panel (another process, perhaps another machine) sends one request at a
time, as four frames, and gets one JSON reply (the contract and the panel's client:
station.control_channel):

    request  [identity, MAC, stamp, body]     stamp = sender | seq | t_ms (UTC)
             MAC = HMAC-SHA256(token, identity NUL stamp body) in hex
             body = {"cmd": ..., "args": {...}, "user": "for whom a delegate (the panel) asks"}
    reply    {"ok": true, "result": ...} | {"ok": false, "error": {"type": ..., "message": ...}}

Authenticated by default and before anything is parsed: the identity must be
one the station knows and the MAC must match (hmac.compare_digest) before the
body is even scanned; `station serve` creates its token on first start
(`ensure_token`, 256 random bits in a file only its owner may read, 0600)
unless one is given. Then fresh and new (`ReplayGuard`): a time stamp more than
FRESH_WINDOW_S from the station's UTC clock is refused as Stale, a seq its sender
has used already as Replay (a captured frame sent again from any socket), each
refusal logged (at most one line per kind every REFUSAL_LOG_S, with the count held
back). Bounded and flat: zmq drops a frame over MAX_REQUEST_BYTES
(ZMQ_MAXMSGSIZE), and a body nested deeper than MAX_DEPTH is refused by a scan
before json.loads (whose recursion a 100 kB `[[[[` once turned into a
RecursionError that killed this thread). Who acted is the authenticated
identity: the event log records `pause by panel` or, when the panel relays a
logged-in user, `pause by bob via panel`; a name in the message alone is never
trusted.

Encrypted and admitted by key when given `keys_dir` (what `station serve` does,
with its telemetry keys, station.telemetry): the socket is a CURVE server whose
ZAP handler admits only the public keys in keys_dir/allowed (the panel's). zmq
holds every frame of a message until the last one arrives (ZMQ_MAXMSGSIZE bounds
each frame, nothing their count: one message of 3000 frames of 60 kB took a
server without keys from 106 to 440 MiB); a peer without an allowed key never
completes the handshake, so it gets no frame into this process at all.

Garbage cannot hold up a request: one I/O thread owns the ROUTER socket and only
screens (a message without a REQ envelope is dropped unanswered, an
unauthenticated one refused, a few microseconds each; zmq fair-queues the peers
and holds at most RCV_HWM messages of each), a worker thread answers the
authenticated requests in order, and an emergency stop is done in the I/O thread
the moment it is screened, ahead of whatever the worker is doing (a start or
resume received before it and not yet begun is then refused, not run; one
already under way ends before its first step, its outcome recorded: the run is
handed the engine's stop count as of its request, station.engine.runner.StopCount).
A REP socket, as before, lost track of its envelope on raw TCP garbage and sent
the next replies nowhere.

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
import queue
import threading
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from drivers.errors import DriverError
from station.cli.controller import StationController
from station.clock import host_clock, utc_s
from station.control_channel import (
    CONTROL_ACTIONS,
    DEFAULT_IDENTITY,
    FRESH_WINDOW_S,
    MAX_DEPTH,
    MAX_REQUEST_BYTES,
    STAMP,
    ControlError,
    Stamp,
    nesting_depth,
    request_mac,
)
from station.engine.context import ValidationError
from station.engine.params import ParameterError
from station.engine.registry import ProcedureError
from station.engine.runner import StopCount
from station.jsonsafe import json_safe
from station.provenance import ProvenanceError
from station.store import StoreError
from station.telemetry import STATION_CERT

log = logging.getLogger(__name__)
REQUEST_ERRORS = (
    ControlError, ProcedureError, ParameterError, ValidationError, DriverError, StoreError, KeyError, TypeError,
    ProvenanceError,
)  # fmt: skip
MAX_SENDERS = 1024  # clients whose frames may still be fresh (a panel has one per station, a CLI call one)
ZAP_DOMAIN = b"station-control"
RCV_HWM = 16  # messages queued per peer: a flooding peer waits on its own TCP window, not the others' turn
BATCH = 64  # messages screened before the I/O thread looks at the worker's replies again
REFUSAL_LOG_S = 10.0  # at most one log line per kind of refusal in this many seconds
MOTION = ("start", "resume_session", "resume")  # refused if an emergency stop came after they were received


def _error(kind: str, message: str) -> dict:
    return {"ok": False, "error": {"type": kind, "message": message}}


class Request(NamedTuple):
    """An authenticated, fresh, parsed request, with the stop counts when it was received (this channel's emergency
    stops, and the engine's aborts and stops by any path, which a run it starts ends on); `done_in` the session
    it was done in already (an emergency stop, "" if none), which the worker only records."""

    route: list[bytes]
    identity: str
    body: dict
    estops: int
    stops: StopCount | None = None
    done_in: str | None = None


class ReplayGuard:
    """Refuses a stale frame and a second use of a sender's seq; remembers at most max_senders senders.

    A sender is forgotten once its newest stamp is older than the window: every frame it sent is stale by
    then. A new sender while max_senders are still fresh is refused (forgetting one would reopen its replays)."""

    def __init__(self, window_s: float = FRESH_WINDOW_S, max_senders: int = MAX_SENDERS) -> None:
        self.window_s = window_s
        self.max_senders = max_senders
        self._last: dict[tuple[bytes, bytes], tuple[int, float]] = {}  # (identity, sender) -> (seq, newest t_s)

    def __len__(self) -> int:
        return len(self._last)

    def admit(self, identity: bytes, stamp: Stamp, now_s: float) -> dict | None:
        """None if the frame is fresh and new (and is recorded as used); otherwise the refusal."""
        skew_s = stamp.t_s - now_s
        if abs(skew_s) > self.window_s:
            why = "a stale or replayed frame, or unsynchronised clocks"
            return _error("Stale", f"stamp t = {stamp.t_s:.3f} (UTC s) is {skew_s:+.1f} s from the station's clock; "
                          f"allowed within {self.window_s:g} s ({why})")  # fmt: skip
        key = (identity, stamp.sender)
        last = self._last.get(key)
        if last is not None and stamp.seq <= last[0]:
            return _error("Replay", f"seq = {stamp.seq} of sender {stamp.sender.hex()} ({identity.decode()}): used "
                          f"already; allowed above {last[0]} (a replayed frame)")  # fmt: skip
        if last is None and len(self._last) >= self.max_senders:
            self._last = {k: v for k, v in self._last.items() if v[1] >= now_s - self.window_s}
            if len(self._last) >= self.max_senders:
                return _error("TooManyClients", f"{len(self._last)} senders within {self.window_s:g} s; allowed "
                              f"{self.max_senders} (sender {stamp.sender.hex()} refused)")  # fmt: skip
        self._last[key] = (stamp.seq, max(stamp.t_s, last[1]) if last is not None else stamp.t_s)
        return None


class RefusalLog:
    """Counts refused frames by kind and logs them, at most one line per kind every interval_s (with the count
    held back since the last line), so that a flood costs no more than a counter."""

    def __init__(self, interval_s: float = REFUSAL_LOG_S) -> None:
        self.interval_s = interval_s
        self.counts: Counter[str] = Counter()
        self._held: Counter[str] = Counter()
        self._next_s: dict[str, float] = {}

    def note(self, kind: str, message: Callable[[], str]) -> None:
        self.counts[kind] += 1
        now_s = host_clock().now_s()
        if now_s < self._next_s.get(kind, float("-inf")):
            self._held[kind] += 1
            return
        held = self._held.pop(kind, 0)
        log.warning("control: refused %s: %s%s", kind, message(), f" ({held} more since the last line)" if held else "")
        self._next_s[kind] = now_s + self.interval_s


def _peer(frame: zmq.Frame) -> str:
    try:
        return f"from {frame.get('Peer-Address')}"
    except zmq.ZMQError:  # the peer's connection is gone (or it sent no such property)
        return "from an address no longer known"


class ControlServer:
    """Serves control requests for one controller: an I/O thread that screens, a worker that answers."""

    def __init__(
        self,
        controller: StationController,
        endpoint: str,
        *,
        token: str,
        identities: tuple[str, ...] = (DEFAULT_IDENTITY,),
        context: zmq.Context | None = None,
        window_s: float = FRESH_WINDOW_S,
        keys_dir: str | Path | None = None,
    ) -> None:
        if not token:
            raise ControlError("the control channel needs a token (ensure_token creates one)")
        if keys_dir is not None and context is not None:
            raise ControlError("keys_dir needs the server's own zmq context (its ZAP handler admits the keys)")
        self.controller = controller
        self._tokens = {name.encode(): token for name in identities}
        self.guard = ReplayGuard(window_s)
        self.refusals = RefusalLog()
        self._own_ctx = context is None  # its own I/O thread, and no ZAP handler (telemetry's) to consult
        self._ctx = context or zmq.Context()
        self._sock = self._ctx.socket(zmq.ROUTER)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.MAXMSGSIZE, MAX_REQUEST_BYTES)
        self._sock.setsockopt(zmq.RCVHWM, RCV_HWM)
        self._sock.setsockopt(zmq.HANDSHAKE_IVL, 2000)  # a peer that never completes its greeting is dropped
        # With a ZAP domain libzmq refuses ZMTP 1.0/2.0 greetings, as random bytes read: without it, 64 kB of them
        # became some 60 messages of random frames. No ZAP handler in the context: NULL peers are let in.
        self._sock.setsockopt(zmq.ZAP_DOMAIN, ZAP_DOMAIN)
        self._auth: ThreadAuthenticator | None = None
        if keys_dir is not None:  # CURVE: only the holders of an allowed key get as far as sending a frame
            keys = Path(keys_dir)
            self._auth = ThreadAuthenticator(self._ctx)
            self._auth.start()
            self._auth.configure_curve(domain=ZAP_DOMAIN.decode(), location=str(keys / "allowed"))
            public, secret = zmq.auth.load_certificate(keys / f"{STATION_CERT}.key_secret")
            self._sock.curve_publickey, self._sock.curve_secretkey = public, secret
            self._sock.curve_server = True
        self._sock.bind(endpoint)
        self.endpoint = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._replies_at = f"inproc://control-replies-{id(self):x}"
        self._replies = self._ctx.socket(zmq.PULL)
        self._replies.bind(self._replies_at)
        self._jobs: queue.SimpleQueue[Request | None] = queue.SimpleQueue()
        self._estops = 0
        self._stop = threading.Event()
        self._served = host_clock().event()
        self._worked = host_clock().event()
        self._thread = threading.Thread(target=self._serve, name="control", daemon=True)
        self._worker = threading.Thread(target=self._work, name="control-worker", daemon=True)
        self._handlers: dict[str, Callable[..., Any]] = {
            "status": lambda a: controller.status(),
            "library": lambda a: controller.library(),
            "plan": lambda a: controller.plan(a["procedure"], a.get("params", {}), checked=True)[1].to_json(),
            "start": self._start,
            "resume_session": self._resume_session,
            "pause": lambda a: controller.pause(),
            "resume": lambda a: controller.resume(),
            "abort": lambda a: controller.abort(),
            "acknowledge": lambda a: controller.engine.acknowledge(),
            "reset": lambda a: controller.reset(),
            "estop": lambda a: controller.emergency_stop(),
            "inject": self._inject,
        }

    def start(self) -> ControlServer:
        self._worker.start()
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._jobs.put(None)
        if self._worker.is_alive():
            self._worked.wait(timeout_s=2.0)
        if self._thread.is_alive():
            self._served.wait(timeout_s=2.0)
        self._sock.close()
        self._replies.close()
        if self._auth is not None:
            self._auth.stop()
        if self._own_ctx and (self._worked.is_set() or not self._worker.is_alive()):  # else a socket is still open
            self._ctx.term()

    def _start(self, a: dict, stops: StopCount | None = None) -> dict:
        uid, plan = self.controller.start(
            a["procedure"], a.get("params", {}), instrument_serial=str(a.get("instrument_serial", "")),
            stops_seen=stops,
        )  # fmt: skip
        return {"session_uid": uid, "plan": plan.to_json()}

    def _inject(self, a: dict) -> dict:
        """A test hook: one fault armed in an emulator of a simulated station (drivers.station.SimulatedStation
        .inject); a real station refuses it."""
        inject = getattr(self.controller.hw, "inject_fault", None)
        if inject is None:
            raise ControlError("inject: a real station takes no injected faults")
        try:
            inject(str(a["device"]), str(a["fault"]))
        except ValueError as exc:
            raise ControlError(f"inject: {exc}") from exc
        return {"device": a["device"], "fault": a["fault"]}

    def _resume_session(self, a: dict, stops: StopCount | None = None) -> dict:
        return {"session_uid": self.controller.resume_session(a["uid"], stops_seen=stops)[0]}

    def authenticate(self, frames: list[bytes]) -> tuple[bytes, Stamp, bytes] | dict:
        """(identity, stamp, body) of an authentic, fresh and new request; otherwise the refusal. Nothing is parsed."""
        if len(frames) != 4:
            return _error("Unauthorized", "bad or missing control token (expected identity, MAC, stamp and body "
                          f"frames; got {len(frames)} frames)")  # fmt: skip
        identity, mac, raw_stamp, body = frames
        stamp = Stamp.unpack(raw_stamp)
        if stamp is None:
            return _error("BadRequest", f"stamp of {len(raw_stamp)} bytes; allowed {STAMP.size}")
        if len(body) > MAX_REQUEST_BYTES:
            return _error("BadRequest", f"request of {len(body)} bytes; allowed at most {MAX_REQUEST_BYTES}")
        token = self._tokens.get(identity)
        expected = request_mac(token, identity, raw_stamp, body) if token is not None else b"0" * 64
        if not hmac.compare_digest(mac, expected) or token is None:
            return _error("Unauthorized", "bad or missing control token")
        refusal = self.guard.admit(identity, stamp, utc_s())
        return refusal if refusal is not None else (identity, stamp, body)

    def screen(self, frames: list[bytes]) -> tuple[str, dict] | dict:
        """(identity, request) of an authentic, fresh, new, bounded JSON object; otherwise the refusal."""
        auth = self.authenticate(frames)
        if isinstance(auth, dict):
            return auth
        identity, _, body = auth
        depth = nesting_depth(body, MAX_DEPTH)
        if depth > MAX_DEPTH:
            return _error("BadRequest", f"request nested {depth} deep or more; allowed at most {MAX_DEPTH}")
        try:
            request = json.loads(body)
        except ValueError:
            request = None
        if not isinstance(request, dict):
            return _error("BadRequest", "expected a JSON object")
        return identity.decode(), request

    def handle(self, request: dict, identity: str, *, record: bool = True, stops: StopCount | None = None) -> dict:
        """One parsed request of an authenticated identity to its reply (public for tests and in-process use);
        a control action done goes to the session's event log unless record is False (`record` does it later).
        `stops`: the engine's stop count when the request was received (a run it starts ends on any stop after)."""
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
            result = handler(args, stops) if cmd in ("start", "resume_session") else handler(args)
        except REQUEST_ERRORS as exc:
            return {"ok": False, "error": {"type": type(exc).__name__, "message": str(exc)}}
        except Exception as exc:  # the channel outlives any request: an unexpected error is a reply, not a dead thread
            log.exception("control request %r failed", cmd)
            return {"ok": False, "error": {"type": "InternalError", "message": f"{type(exc).__name__}: {exc}"}}
        if record:
            self.record(request, identity)
        return {"ok": True, "result": result}

    def record(self, request: dict, identity: str, uid: str | None = None) -> None:
        """A control action done, to the event log of session uid (default: the current one) with who asked."""
        cmd, args = request.get("cmd"), request.get("args") or {}
        uid = self.controller.engine.progress.session_uid if uid is None else uid
        if cmd in CONTROL_ACTIONS and uid:
            user = str(request.get("user") or "")[:64]
            who = f"{user} via {identity}" if user and user != identity else identity
            try:
                self.controller.store.add_event(uid, "control", f"{cmd} by {who}" + (f" {args}" if args else ""))
            except Exception as exc:  # the action was done; a store that cannot take its record must not undo it
                log.error("control %s by %s not recorded: %s", cmd, who, exc)

    def _take(self, peer: zmq.Frame, frames: list[bytes]) -> None:
        """Screen one message off the ROUTER (`peer` its routing id, `frames` the rest): drop, refuse, stop at once,
        or queue for the worker."""
        if len(frames) < 2 or frames[0]:  # no REQ envelope [b"", ...]: nobody to answer
            self.refusals.note("NoEnvelope", lambda: f"a message of {len(frames)} frames without a REQ envelope "
                               f"({_peer(peer)})")  # fmt: skip
            return
        route = [peer.bytes, b""]
        screened = self.screen(frames[1:])
        if isinstance(screened, dict):
            self.refusals.note(screened["error"]["type"], lambda: f"{screened['error']['message']} ({_peer(peer)})")
            self._reply(route, screened)
            return
        identity, request = screened
        stops = self.controller.engine.stop_count()  # before any stop this message may be
        if request.get("cmd") == "estop":  # ahead of everything the worker has queued or is doing
            self._estops += 1
            reply = self.handle(request, identity, record=False)
            self._reply(route, reply)
            if reply["ok"]:  # recorded by the worker: a busy store cannot delay this thread
                uid = self.controller.engine.progress.session_uid or ""
                self._jobs.put(Request(route, identity, request, self._estops, stops, done_in=uid))
            return
        self._jobs.put(Request(route, identity, request, self._estops, stops))

    def _reply(self, route: list[bytes], reply: dict) -> None:
        self._sock.send_multipart([*route, json.dumps(json_safe(reply)).encode()])

    def _serve(self) -> None:
        try:
            poller = zmq.Poller()
            poller.register(self._sock, zmq.POLLIN)
            poller.register(self._replies, zmq.POLLIN)
            while not self._stop.is_set():
                ready = dict(poller.poll(100))
                if self._replies in ready:
                    while self._replies.poll(0):
                        self._sock.send_multipart(self._replies.recv_multipart())
                if self._sock in ready:
                    for _ in range(BATCH):
                        try:
                            peer = self._sock.recv(zmq.NOBLOCK, copy=False)  # the routing id, with the metadata
                        except zmq.Again:
                            break
                        frames = []
                        while self._sock.rcvmore:
                            frames.append(self._sock.recv())
                        try:
                            self._take(peer, frames)
                        except Exception:  # the channel outlives any message
                            log.exception("control: a message could not be screened")
        finally:
            self._served.set()

    def _work(self) -> None:
        push = self._ctx.socket(zmq.PUSH)
        push.setsockopt(zmq.LINGER, 0)
        push.connect(self._replies_at)
        try:
            while (job := self._jobs.get()) is not None:
                if job.done_in is not None:
                    self.record(job.body, job.identity, job.done_in)
                    continue
                if job.body.get("cmd") in MOTION and job.estops != self._estops:
                    reply = _error("ControlError", f"cmd = {job.body.get('cmd')!r} refused: an emergency stop "
                                   "came after it was received (reset, then ask again)")  # fmt: skip
                else:
                    reply = self.handle(job.body, job.identity, stops=job.stops)
                push.send_multipart([*job.route, json.dumps(json_safe(reply)).encode()])
        finally:
            push.close()
            self._worked.set()
