"""The station's control channel over a real zmq REQ/REP pair: authenticated before anything is parsed, bounded
and flat messages, the acting identity from the authentication, a token file only its owner may read."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zmq

from drivers.config import load_station_config
from drivers.station import simulated_station
from station.cli.control import ControlServer
from station.cli.controller import StationController
from station.clock import VirtualClock, utc_s
from station.control_channel import (
    MAX_DEPTH,
    MAX_REQUEST_BYTES,
    ControlClient,
    ControlError,
    Stamp,
    ensure_token,
    request_frames,
    request_mac,
)
from station.store import SessionStore
from station.telemetry import TelemetryPublisher, curve_client, ensure_telemetry_keys
from station.twin.config import default_twin

pytestmark = pytest.mark.timeout(60)
CONFIG = load_station_config(Path(__file__).parents[2] / "config" / "stations/vibration-sim.toml")
TOKEN = "t0ken" * 8


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[ControlServer]:
    tmp = tmp_path_factory.mktemp("control")
    sim = simulated_station(CONFIG, default_twin())
    store = SessionStore(tmp / "station.sqlite")
    controller = StationController(sim.devices, store, CONFIG.station_model(), reports_dir=tmp)
    srv = ControlServer(controller, "tcp://127.0.0.1:*", token=TOKEN).start()
    yield srv
    srv.close()
    controller.close()
    sim.close()
    store.close()


def raw_request(endpoint: str, frames: list[bytes], timeout_s: float = 3.0) -> dict | None:
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, round(timeout_s * 1000))
    sock.connect(endpoint)
    try:
        sock.send_multipart(frames)
        return json.loads(sock.recv())
    except zmq.Again:
        return None
    finally:
        sock.close()


_SEQ = iter(range(1, 1 << 62))


def signed(body: bytes, identity: bytes = b"panel", token: str = TOKEN, t_s: float | None = None) -> list[bytes]:
    stamp = Stamp(b"test-raw", next(_SEQ), utc_s() if t_s is None else t_s)
    return request_frames(token, identity, stamp, body)


def test_a_flood_of_brackets_is_refused_and_the_channel_lives_on(server) -> None:
    reply = raw_request(server.endpoint, signed(b"[" * (MAX_REQUEST_BYTES - 10)))
    assert reply is not None and reply["error"]["type"] == "BadRequest"
    assert f"allowed at most {MAX_DEPTH}" in reply["error"]["message"]
    deep = json.dumps({"cmd": "plan", "args": {"params": {"a": [[[1]]]}}}).encode()  # 6 deep
    assert "nested" in raw_request(server.endpoint, signed(deep))["error"]["message"]
    ok = raw_request(server.endpoint, signed(json.dumps({"cmd": "status"}).encode()))
    assert ok["ok"] is True and "state" in ok["result"]


def test_an_oversized_message_is_dropped_by_zmq_and_the_channel_lives_on(server) -> None:
    assert raw_request(server.endpoint, signed(b" " * (MAX_REQUEST_BYTES + 1)), timeout_s=1.0) is None
    assert raw_request(server.endpoint, signed(json.dumps({"cmd": "status"}).encode()))["ok"] is True


@pytest.mark.parametrize(
    ("frames", "kind"),
    [
        ([b"[" * 50_000], "Unauthorized"),  # one frame: the old format, or garbage
        ([b"panel", b"0" * 64, b"[" * 50_000], "Unauthorized"),  # the old three frames
        ([b"panel", b"0" * 64, b"s" * 24, b"[" * 50_000], "Unauthorized"),  # a wrong MAC over a hostile body
        (signed(b"{}", identity=b"mallory"), "Unauthorized"),  # an identity the station does not know
        (signed(json.dumps({"cmd": "estop"}).encode(), token="guess" * 8), "Unauthorized"),
        ([b"panel", request_mac(TOKEN, b"panel", b"", b"{}"), b"", b"{}"], "BadRequest"),  # no stamp: not even read
    ],
)
def test_unauthenticated_requests_are_refused_before_parsing(server, frames, kind) -> None:
    reply = raw_request(server.endpoint, frames)
    assert reply["ok"] is False and reply["error"]["type"] == kind, reply


def test_the_actor_is_the_authenticated_identity(server) -> None:
    client = ControlClient(server.endpoint, token=TOKEN, timeout_s=10)
    ctl = server.controller
    try:
        started = client.request("start", {"procedure": "integral_precession",
                                           "params": {"positions_deg": [0, 60, 180, 240], "freqs_hz": [10],
                                                      "window_s": 30}},
                                 user="alice")  # fmt: skip
        assert started["ok"], started
        uid = started["result"]["session_uid"]
        assert client.request("abort")["ok"]  # no user relayed: the identity itself
        ctl.wait(30)
        log = [e["message"] for e in ctl.store.events(uid) if e["kind"] == "control"]
        assert log[0].startswith("start by alice via panel")
        assert log[1] == "abort by panel"
    finally:
        client.close()


def test_the_token_file_is_made_owner_only_and_a_readable_one_refused(tmp_path) -> None:
    path = tmp_path / "control.token"
    token = ensure_token(path)
    assert len(token) == 64 and oct(path.stat().st_mode & 0o777) == "0o600"
    assert ensure_token(path) == token  # made once
    os.chmod(path, 0o644)
    with pytest.raises(ControlError, match="mode 644 lets others read it; allowed 600"):
        ensure_token(path)


def test_a_server_without_a_token_is_refused() -> None:
    with pytest.raises(ControlError, match="needs a token"):
        ControlServer(None, "tcp://127.0.0.1:*", token="")  # type: ignore[arg-type]


def test_depth_scan_reads_the_largest_message_and_skips_brackets_in_strings() -> None:
    from station.control_channel import nesting_depth

    body = json.dumps({"cmd": "start", "args": {"params": {"positions_deg": list(range(9000))}}}).encode()
    assert len(body) < MAX_REQUEST_BYTES
    assert nesting_depth(body, MAX_DEPTH) == 4
    assert nesting_depth(b'{"a": "[[[[[[[["}', MAX_DEPTH) == 1  # brackets in strings do not count


def _sub(endpoint: str, keys: Path | None = None, name: str = "panel") -> zmq.Socket:
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.subscribe(b"")
    if keys is not None:
        curve_client(sub, keys, name)
    sub.connect(endpoint)
    return sub


def test_telemetry_is_readable_only_with_allowed_keys(tmp_path) -> None:
    import zmq.auth

    keys = ensure_telemetry_keys(tmp_path / "telemetry-keys")
    assert oct((keys / "station.key_secret").stat().st_mode & 0o777) == "0o600"
    zmq.auth.create_certificates(keys, "mallory")  # a key pair the station does not allow
    pub = TelemetryPublisher("tcp://127.0.0.1:*", "sim", VirtualClock(1.0), keys_dir=keys)
    allowed, plain, stranger = _sub(pub.endpoint, keys), _sub(pub.endpoint), _sub(pub.endpoint, keys, "mallory")
    try:
        got: dict[str, int] = {"allowed": 0, "plain": 0, "stranger": 0}
        t0 = time.monotonic()
        while time.monotonic() - t0 < 3.0:  # 3 s of publishing: past the slow joiner and the CURVE handshake
            pub.publish("status", {"state": "idle"})
            for label, sock in (("allowed", allowed), ("plain", plain), ("stranger", stranger)):
                while sock.poll(0):
                    sock.recv_multipart()
                    got[label] += 1
            time.sleep(0.01)
    finally:
        for sock in (allowed, plain, stranger):
            sock.close()
        pub.close()
    assert got["allowed"] > 50 and got["plain"] == 0 and got["stranger"] == 0, got


def test_a_captured_frame_sent_again_is_refused_and_logged(server, caplog) -> None:
    """The issue's attack: status, estop and reset frames captured and sent again from a new socket."""
    frames = {cmd: signed(json.dumps({"cmd": cmd}).encode()) for cmd in ("status", "estop", "reset")}
    for cmd, captured in frames.items():
        assert raw_request(server.endpoint, captured)["ok"] is True, cmd
    before = server.refusals.counts["Replay"]
    with caplog.at_level("WARNING", logger="station.cli.control"):
        for cmd, captured in frames.items():
            reply = raw_request(server.endpoint, captured)
            assert reply["error"]["type"] == "Replay", (cmd, reply)
            assert "used already; allowed above" in reply["error"]["message"]
    assert server.refusals.counts["Replay"] == before + 3
    assert any("refused Replay" in r.getMessage() and "(from 127.0.0.1)" in r.getMessage() for r in caplog.records)


def test_a_stale_or_future_frame_is_refused(server) -> None:
    status = json.dumps({"cmd": "status"}).encode()
    for offset_s in (-31.0, 31.0, -3600.0):
        reply = raw_request(server.endpoint, signed(status, t_s=utc_s() + offset_s))
        assert reply["error"]["type"] == "Stale", reply
        assert "allowed within 30 s" in reply["error"]["message"]
    assert raw_request(server.endpoint, signed(status, t_s=utc_s() - 25.0))["ok"] is True  # skew within the window


def test_a_lower_seq_is_refused_and_another_sender_has_its_own() -> None:
    from station.cli.control import ReplayGuard

    guard = ReplayGuard(window_s=30.0, max_senders=3)
    assert guard.admit(b"panel", Stamp(b"A" * 8, 5, 100.0), 100.0) is None
    assert guard.admit(b"panel", Stamp(b"A" * 8, 4, 100.0), 100.0)["error"]["type"] == "Replay"
    assert guard.admit(b"panel", Stamp(b"A" * 8, 5, 100.0), 100.0)["error"]["type"] == "Replay"
    assert guard.admit(b"panel", Stamp(b"B" * 8, 1, 100.0), 100.0) is None
    assert guard.admit(b"cli", Stamp(b"A" * 8, 1, 100.0), 100.0) is None  # identities apart
    full = guard.admit(b"panel", Stamp(b"C" * 8, 1, 110.0), 110.0)  # a fourth sender while three are fresh
    assert full["error"]["type"] == "TooManyClients" and "allowed 3" in full["error"]["message"]
    assert guard.admit(b"panel", Stamp(b"C" * 8, 1, 131.0), 131.0) is None  # the others' frames are stale now
    assert len(guard) == 1
    assert guard.admit(b"panel", Stamp(b"A" * 8, 5, 100.0), 131.0)["error"]["type"] == "Stale"  # forgotten, stale


def test_raw_tcp_garbage_does_not_hold_up_the_next_request(server) -> None:
    """A REP socket lost its envelope on such bytes and sent the next replies nowhere (10 s timeouts)."""
    import socket

    host, port = server.endpoint.removeprefix("tcp://").rsplit(":", 1)
    client = ControlClient(server.endpoint, token=TOKEN, timeout_s=5)
    try:
        for _ in range(8):
            with socket.create_connection((host, int(port))) as s:
                s.sendall(os.urandom(65536))
            t0 = time.perf_counter()
            assert client.request("status")["ok"] is True
            assert time.perf_counter() - t0 < 1.0
    finally:
        client.close()


def test_an_emergency_stop_is_answered_within_100_ms_while_garbage_arrives(server) -> None:
    """Estop and status round trips from a client while a flood process sends every kind of garbage
    (tests/control_garbage: raw TCP bursts, REQ-shaped frames with a wrong MAC, envelope-less multipart, a captured
    estop replayed) and two busy loops take both cores: a busy 2-core machine under attack.

    Why 100 ms holds with a margin: raw bytes never become messages (the ZAP domain refuses ZMTP 1.0 greetings);
    the I/O thread only screens (some 10 us a message, HMAC included), zmq fair-queues the peers and holds at most
    RCV_HWM of each, so a request waits behind one message of each flooding socket (a handful); the stop is done
    in the I/O thread (0.3 ms on the simulated station), ahead of the worker. What is left is the scheduler and
    the GIL: this process's threads (client, I/O, worker, zmq's) share two cores with three busy processes, a
    slice of a few ms each (CFS), and the client shares the GIL with the server (a panel would not). Measured
    here: a median of 0.4-6 ms, the worst of 40 stops 4-30 ms; every stop must be answered within the issue's
    100 ms. A status goes through the worker thread, which waits for the GIL while the I/O thread screens (5 ms
    switch interval, several handoffs a request): its worst has been 136 ms with the suite's two workers and 1.7 s
    with four on two cores (seven busy processes), so it is held to being answered within the client's 5 s timeout
    (a request that times out replies ok = false)."""
    from busy import busy_loops
    from control_garbage import flooding

    captured = signed(json.dumps({"cmd": "estop"}).encode())
    assert raw_request(server.endpoint, captured)["ok"] is True
    client = ControlClient(server.endpoint, token=TOKEN, timeout_s=5)
    latencies_ms: dict[str, list[float]] = {"estop": [], "status": []}
    before = dict(server.refusals.counts)
    try:
        with busy_loops(2), flooding(server.endpoint, replay=captured):
            time.sleep(0.5)  # the flood under way
            for _ in range(40):
                for cmd, lat in latencies_ms.items():
                    t0 = time.perf_counter()
                    reply = client.request(cmd)
                    lat.append((time.perf_counter() - t0) * 1000)
                    assert reply["ok"] is True, reply
                    time.sleep(0.02)
        assert client.request("reset")["ok"] is True
    finally:
        client.close()
    refused = {k: v - before.get(k, 0) for k, v in server.refusals.counts.items()}
    for cmd, lat in latencies_ms.items():
        print(f"{cmd} under garbage: median {sorted(lat)[20]:.2f} ms, max {max(lat):.2f} ms")
    print(f"refused meanwhile {refused}")
    assert refused.get("Unauthorized", 0) > 10 and refused.get("Replay", 0) > 10  # the flood did arrive
    assert max(latencies_ms["estop"]) < 100.0, latencies_ms


def test_an_emergency_stop_overtakes_a_slow_request_and_cancels_a_queued_start() -> None:
    """The worker is busy (a library call that takes as long as it likes) and a start waits behind it: the stop is
    done and answered at once, and the start, received before the stop, is refused when its turn comes."""
    import threading

    from control_fuzz import TOKEN as FUZZ_TOKEN
    from control_fuzz import RecordingController

    release = threading.Event()

    class Slow(RecordingController):
        def library(self) -> list:
            self.calls.append("library")
            release.wait()
            return []

    controller = Slow()
    srv = ControlServer(controller, "tcp://127.0.0.1:*", token=FUZZ_TOKEN).start()  # type: ignore[arg-type]
    clients = [ControlClient(srv.endpoint, token=FUZZ_TOKEN, timeout_s=10) for _ in range(3)]
    replies: dict[str, dict] = {}

    def ask(client: ControlClient, cmd: str) -> None:
        replies[cmd] = client.request(cmd, {"procedure": "p"})

    threads = [
        threading.Thread(target=ask, args=(c, cmd)) for c, cmd in zip(clients, ("library", "start"), strict=False)
    ]
    try:
        for t in threads:
            t.start()
            time.sleep(0.2)  # library taken by the worker, then start queued behind it
        t0 = time.perf_counter()
        assert clients[2].request("estop")["ok"] is True
        assert time.perf_counter() - t0 < 0.1 and controller.calls == ["library", "emergency_stop"]
        release.set()
        for t in threads:
            t.join(timeout=10)
        assert replies["library"]["ok"] is True
        assert replies["start"]["error"]["type"] == "ControlError"
        assert "an emergency stop came after it was received" in replies["start"]["error"]["message"]
        assert "start" not in controller.calls
    finally:
        release.set()
        for c in clients:
            c.close()
        srv.close()
