"""Telemetry of one station over pyzmq PUB, for the panel and anyone else who listens.

Each message is two frames: the topic `<station>.<topic>` (so a SUB can
filter by station and topic) and a JSON document

    {"station": id, "topic": t, "seq": n, "t_s": station time, "wall_s": Unix time, "data": {...}}

`seq` counts every message of the publisher from 0, so a subscriber sees any
gap (the slow-joiner loss at connect, or a high-water-mark drop). Topics:

    state        {"state", "session_uid", "procedure"}
    progress     Progress.to_json(): key, done, total, fraction, elapsed_s, estimate_*_s, faults
    window       {"session_uid", "key", "event", "elapsed_s", "expected_s", "preset_pulses", "pulses_est",
                 ["rate_radps"]}
    motion       {"freq_hz", "commanded_hz", "index_deg"}
    trace        {"session_uid", "t_s": [...], "z_m": [...], "freq_hz"}  table displacement from the grating, decimated
                 honestly (`envelope`: the min and the max of each time bucket, in time order)
    point        a PointRecord as JSON
    measurement  {"key", "kind", "values"}
    event        {"kind", "message", "level"}
    fault        {"kind", "message"}
    analysis     {"session_uid", "summary", "results"}

The socket binds (the station is the stable end) and is used from one thread
at a time under a lock: zmq sockets are not thread-safe.

Readable only by those allowed: with `keys_dir` (what `station serve` uses;
`ensure_telemetry_keys` makes it on first start) the PUB socket is a CURVE
server and a ZAP authenticator admits only the client public keys in
`keys_dir/allowed` (the panel's, made with it); every message is encrypted.
A subscriber sets `curve_client(sock, keys_dir)`. Secret keys are owner-only (0600).
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from station.clock import Clock
from station.jsonsafe import json_safe


def envelope(t_s: np.ndarray, z_m: np.ndarray, buckets: int) -> tuple[np.ndarray, np.ndarray]:
    """At most 2 * buckets samples that keep every excursion: the min and the max of each of `buckets` equal
    stretches of samples, each at its own time and in time order (a plot of them shows the true envelope where
    a stride would alias the motion into scattered dots)."""
    n = len(t_s)
    if n <= 2 * buckets:
        return np.asarray(t_s), np.asarray(z_m)
    edges = np.linspace(0, n, buckets + 1).astype(int)
    starts = edges[:-1]
    i_min = np.array([a + int(np.argmin(z_m[a:b])) for a, b in zip(starts, edges[1:], strict=True)])
    i_max = np.array([a + int(np.argmax(z_m[a:b])) for a, b in zip(starts, edges[1:], strict=True)])
    keep = np.unique(np.concatenate([i_min, i_max]))  # sorted: time order
    return np.asarray(t_s)[keep], np.asarray(z_m)[keep]


SNDHWM = 10_000  # messages queued per subscriber before zmq drops (the panel must not slow the station)


STATION_CERT = "station"
CLIENT_CERT = "panel"


def ensure_telemetry_keys(keys_dir: str | Path) -> Path:
    """The station's CURVE keys and its panel's, made on first use; the panel's public key in keys_dir/allowed."""
    keys_dir = Path(keys_dir)
    allowed = keys_dir / "allowed"
    if not (keys_dir / f"{STATION_CERT}.key_secret").is_file():
        keys_dir.mkdir(parents=True, exist_ok=True)
        os.chmod(keys_dir, 0o700)
        for name in (STATION_CERT, CLIENT_CERT):
            zmq.auth.create_certificates(keys_dir, name)
            os.chmod(keys_dir / f"{name}.key_secret", 0o600)
        allowed.mkdir(exist_ok=True)
        (allowed / f"{CLIENT_CERT}.key").write_bytes((keys_dir / f"{CLIENT_CERT}.key").read_bytes())
    return keys_dir


def curve_client(sock: zmq.Socket, keys_dir: str | Path, name: str = CLIENT_CERT) -> None:
    """Make a SUB socket a CURVE client of the station whose keys are in keys_dir (before connect)."""
    keys_dir = Path(keys_dir)
    server_public, _ = zmq.auth.load_certificate(keys_dir / f"{STATION_CERT}.key")
    public, secret = zmq.auth.load_certificate(keys_dir / f"{name}.key_secret")
    sock.curve_serverkey, sock.curve_publickey, sock.curve_secretkey = server_public, public, secret


class TelemetryPublisher:
    """PUB socket of one station; `publish(topic, data)` is the engine's Publisher."""

    def __init__(
        self,
        endpoint: str,
        station_id: str,
        clock: Clock,
        context: zmq.Context | None = None,
        keys_dir: str | Path | None = None,
    ) -> None:
        self.station_id = station_id
        self.clock = clock
        self._ctx = context or zmq.Context.instance()
        self._auth: ThreadAuthenticator | None = None
        self._sock = self._ctx.socket(zmq.PUB)
        if keys_dir is not None:  # only the allowed clients' keys get the (encrypted) telemetry
            keys_dir = Path(keys_dir)
            self._auth = ThreadAuthenticator(self._ctx)
            self._auth.start()
            self._auth.configure_curve(domain="*", location=str(keys_dir / "allowed"))
            public, secret = zmq.auth.load_certificate(keys_dir / f"{STATION_CERT}.key_secret")
            self._sock.curve_publickey, self._sock.curve_secretkey = public, secret
            self._sock.curve_server = True
        self._sock.setsockopt(zmq.SNDHWM, SNDHWM)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.bind(endpoint)
        self.endpoint = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)  # the real port when bound to :0
        self._lock = threading.Lock()
        self._seq = 0

    def publish(self, topic: str, data: dict) -> None:
        with self._lock:
            if self._sock.closed:
                return
            doc = {"station": self.station_id, "topic": topic, "seq": self._seq, "t_s": self.clock.now_s(),
                   "wall_s": time.time(), "data": json_safe(data)}  # fmt: skip
            self._seq += 1
            body = json.dumps(doc, allow_nan=False).encode()
            self._sock.send_multipart([f"{self.station_id}.{topic}".encode(), body])

    def close(self) -> None:
        with self._lock:
            self._sock.close()
        if self._auth is not None:
            self._auth.stop()
