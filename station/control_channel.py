"""The control channel's contract, as both ends speak it: framing, authentication, bounds, the token, the client.

One request at a time, as four frames, and one JSON reply:

    request  [identity, MAC, stamp, body]
             stamp = sender (8 random bytes per client) | seq (u64, +1 per request) | t_ms (u64, UTC ms)
             MAC   = HMAC-SHA256(token, identity NUL stamp body) in hex
             body  = {"cmd": ..., "args": {...}, "user": "for whom a delegate (the panel) asks"}
    reply    {"ok": true, "result": ...} | {"ok": false, "error": {"type": ..., "message": ...}}

The station's end is station.cli.control.ControlServer; the panel's is `ControlClient`. A request is
authenticated (`request_mac` under the station's token, `ensure_token`) before anything is parsed, then
fresh (its time stamp within FRESH_WINDOW_S of the station's UTC clock) and new (a seq above the last one
its sender used): a captured frame sent again is refused. Bounded (MAX_REQUEST_BYTES, MAX_DEPTH by
`nesting_depth`) before json.loads.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import struct
import threading
from pathlib import Path
from typing import NamedTuple

import zmq

from station.clock import utc_s
from station.errors import StationFault
from station.telemetry import CLIENT_CERT, curve_client


class ControlError(StationFault):
    """A control request that the station's state does not allow (a run already under way, ...)."""


CONTROL_ACTIONS = ("start", "resume_session", "pause", "resume", "abort", "estop", "acknowledge", "reset", "inject")
MAX_REQUEST_BYTES = 64 * 1024  # a start with a few hundred positions is under 10 kB
MAX_DEPTH = 5  # {"args": {"params": {"positions_deg": [...]}}} is 4 deep
DEFAULT_IDENTITY = "panel"
TOKEN_FILE = "control.token"
FRESH_WINDOW_S = 30.0  # a frame's time stamp this close to the station's UTC clock, either way; NTP keeps hosts closer
STAMP = struct.Struct(">8sQQ")  # sender, seq, t_ms


class Stamp(NamedTuple):
    """Who sent a frame (a client's random sender id), its place in that sender's sequence and when (UTC s)."""

    sender: bytes
    seq: int
    t_s: float

    def pack(self) -> bytes:
        return STAMP.pack(self.sender, self.seq, round(self.t_s * 1000))

    @classmethod
    def unpack(cls, raw: bytes) -> Stamp | None:
        """The stamp in `raw`, None unless it is exactly STAMP.size bytes."""
        if len(raw) != STAMP.size:
            return None
        sender, seq, t_ms = STAMP.unpack(raw)
        return cls(sender, seq, t_ms / 1000)


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


def request_mac(token: str, identity: bytes, stamp: bytes, body: bytes) -> bytes:
    """HMAC-SHA256 of identity NUL stamp body under the token, hex: what authenticates a request and its stamp."""
    return hmac.new(token.encode(), identity + b"\0" + stamp + body, hashlib.sha256).hexdigest().encode()


def request_frames(token: str, identity: bytes, stamp: Stamp, body: bytes) -> list[bytes]:
    """The four frames of one request."""
    packed = stamp.pack()
    return [identity, request_mac(token, identity, packed, body), packed, body]


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


class ControlClient:
    """The panel's side: one request at a time, a bounded wait for the reply, each stamped anew (a random sender
    id per client, seq counting up from 1, the host's UTC time)."""

    def __init__(
        self,
        endpoint: str,
        *,
        token: str | None,
        identity: str = DEFAULT_IDENTITY,
        timeout_s: float = 10.0,
        keys_dir: str | Path | None = None,
    ) -> None:
        self.endpoint = endpoint
        # The station's CURVE keys (station.telemetry): used once the panel's secret key is there (`station serve`
        # makes them and speaks CURVE on its control channel); looked for at each new socket.
        self._keys_dir = None if keys_dir is None else Path(keys_dir)
        self._token = token or ""
        self._identity = identity.encode()
        self._timeout_ms = round(timeout_s * 1000)
        self._ctx: zmq.Context = zmq.Context.instance()
        self._lock = threading.Lock()
        self._sender = secrets.token_bytes(8)
        self._seq = 0
        self._sock = self._new_socket()

    def _new_socket(self) -> zmq.Socket:
        sock = self._ctx.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVTIMEO, self._timeout_ms)
        sock.setsockopt(zmq.SNDTIMEO, self._timeout_ms)
        if self._keys_dir is not None and (self._keys_dir / f"{CLIENT_CERT}.key_secret").is_file():
            curve_client(sock, self._keys_dir)
        sock.connect(self.endpoint)
        return sock

    def request(self, cmd: str, args: dict | None = None, user: str = "") -> dict:
        """The reply document; {"ok": false, "error": {"type": "Timeout"}} if the station does not answer."""
        body = json.dumps({"cmd": cmd, "args": args or {}, "user": user}).encode()
        with self._lock:
            self._seq += 1
            frames = request_frames(self._token, self._identity, Stamp(self._sender, self._seq, utc_s()), body)
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
