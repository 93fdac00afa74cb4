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

from app.control import ControlServer
from app.controller import StationController
from devices.config import load_station_config
from devices.station import simulated_station
from models.config import default_twin
from station.clock import VirtualClock
from station.control_channel import MAX_DEPTH, MAX_REQUEST_BYTES, ControlClient, ControlError, ensure_token, request_mac
from station.store import SessionStore
from station.telemetry import TelemetryPublisher, curve_client, ensure_telemetry_keys

pytestmark = pytest.mark.timeout(60)
CONFIG = load_station_config(Path(__file__).parents[2] / "config" / "station-sim.toml")
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


def signed(body: bytes, identity: bytes = b"panel", token: str = TOKEN) -> list[bytes]:
    return [identity, request_mac(token, identity, body), body]


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
    "frames",
    [
        [b"[" * 50_000],  # one frame: the old format, or garbage
        [b"panel", b"0" * 64, b"[" * 50_000],  # a wrong MAC over a hostile body: refused before the body is read
        [b"mallory", request_mac(TOKEN, b"mallory", b"{}"), b"{}"],  # an identity the station does not know
        signed(json.dumps({"cmd": "estop"}).encode(), token="guess" * 8),
    ],
)
def test_unauthenticated_requests_are_refused_before_parsing(server, frames) -> None:
    reply = raw_request(server.endpoint, frames)
    assert reply["ok"] is False and reply["error"]["type"] == "Unauthorized"


def test_the_actor_is_the_authenticated_identity(server) -> None:
    client = ControlClient(server.endpoint, token=TOKEN, timeout_s=10)
    ctl = server.controller
    try:
        started = client.request("start", {"procedure": "seed000.integral_precession",
                                           "params": {"positions_deg": [0, 90], "freqs_hz": [10], "window_s": 30}},
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
