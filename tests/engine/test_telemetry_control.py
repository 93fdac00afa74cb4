"""Telemetry over a real zmq PUB/SUB pair and control over a real REQ/REP pair."""

from __future__ import annotations

import json
import math
import time

import pytest
import zmq

from station.cli.control import ControlServer
from station.clock import VirtualClock
from station.control_channel import ControlClient
from station.telemetry import TelemetryPublisher

from .conftest import PROCEDURE, QUICK

pytestmark = pytest.mark.timeout(120)


def _subscriber(endpoint: str) -> zmq.Socket:
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(endpoint)
    return sub


def test_messages_are_numbered_json_with_the_station_time() -> None:
    clock = VirtualClock(1000.0, start_s=50.0)
    pub = TelemetryPublisher("tcp://127.0.0.1:*", "bench-1", clock)
    sub = _subscriber(pub.endpoint)
    try:
        # The slow joiner: publish until the subscription is in place, then a known series.
        while not sub.poll(20):
            pub.publish("event", {"kind": "hello"})
        while sub.poll(50):
            sub.recv_multipart()
        for i in range(200):
            pub.publish("window", {"i": i, "rate_radps": math.nan, "arr": [1.0, 2.0]})
        got = []
        while len(got) < 200 and sub.poll(1000):
            topic, body = sub.recv_multipart()
            got.append((topic, json.loads(body)))
    finally:
        sub.close()
        pub.close()
    assert len(got) == 200
    assert {t for t, _ in got} == {b"bench-1.window"}
    seqs = [d["seq"] for _, d in got]
    assert seqs == list(range(seqs[0], seqs[0] + 200))  # no gap
    first = got[0][1]
    assert first["station"] == "bench-1" and first["topic"] == "window" and first["t_s"] >= 50.0
    assert first["data"] == {"i": 0, "rate_radps": None, "arr": [1.0, 2.0]}  # NaN travels as null
    assert abs(first["wall_s"] - time.time()) < 60


def test_control_channel_validates_runs_and_logs_who_asked(make_rig) -> None:
    rig = make_rig(speed=300.0)
    server = ControlServer(rig.controller, "tcp://127.0.0.1:*", token="s3cret").start()
    client = ControlClient(server.endpoint, token="s3cret", timeout_s=20)
    intruder = ControlClient(server.endpoint, token="guess", timeout_s=5)
    try:
        assert intruder.request("pause", user="mallory")["error"]["type"] == "Unauthorized"
        lib = client.request("library")["result"]
        assert PROCEDURE in {p["name"] for p in lib}
        bad = client.request("start", {"procedure": PROCEDURE, "params": {"freqs_hz": [11]}}, user="alice")
        assert bad["ok"] is False and bad["error"]["type"] == "ParameterError"
        assert "'freqs_hz'[0] = 11" in bad["error"]["message"] and "[0.1, 10] Hz" in bad["error"]["message"]
        assert client.request("warp")["error"]["type"] == "UnknownCommand"
        plan = client.request("plan", {"procedure": PROCEDURE, "params": QUICK})["result"]
        assert plan["n_measurements"] == 10 and plan["total_s"] > 0
        started = client.request("start", {"procedure": PROCEDURE, "params": QUICK}, user="alice")["result"]
        uid = started["session_uid"]
        t0 = time.monotonic()
        while client.request("status")["result"]["done"] < 1:
            assert time.monotonic() - t0 < 30
            time.sleep(0.05)
        assert client.request("pause", user="bob")["ok"]
        assert client.request("resume", user="bob")["ok"]
        assert client.request("abort", user="carol")["ok"]
        rig.controller.wait(30)
        log = [e["message"] for e in rig.store.events(uid) if e["kind"] == "control"]
        # who acted: the user a delegate (the panel's identity, authenticated by the token) relays
        assert log[0].startswith("start by alice via panel {'procedure': 'integral_precession'")
        assert log[1:4] == ["pause by bob via panel", "resume by bob via panel", "abort by carol via panel"]
        assert client.request("status")["result"]["state"] == "aborted"
    finally:
        client.close()
        intruder.close()
        server.close()


def test_a_station_that_does_not_answer_is_a_timeout_not_a_hang() -> None:
    client = ControlClient("tcp://127.0.0.1:1", token="t" * 32, timeout_s=0.3)
    t0 = time.monotonic()
    reply = client.request("status")
    assert reply["error"]["type"] == "Timeout" and time.monotonic() - t0 < 2
    assert client.request("status")["error"]["type"] == "Timeout"  # the socket was renewed, not wedged
    client.close()
