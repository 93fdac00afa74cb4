"""Live view endpoints: stations, status, library and the telemetry WebSocket, against a real `station serve`."""

from __future__ import annotations

import json
import time

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from web.auth import SESSION_COOKIE

STATUS_PER_S = 5  # the controller's beacon; the issue asks for at least 5 updates a second


def browser_headers(client: TestClient, origin: str = "http://testserver") -> dict:
    """What a browser sends with its WebSocket handshake (the test client's ws:// host is `testserver`)."""
    return {"cookie": f"{SESSION_COOKIE}={client.cookies[SESSION_COOKIE]}", "origin": origin}


@pytest.fixture
def anonymous(app_client) -> TestClient:
    return TestClient(app_client.app, base_url="http://127.0.0.1")


@pytest.mark.parametrize(
    "path", ["/api/stations", "/api/stations/sim/status", "/api/stations/sim/library", "/api/relay"]
)
def test_live_endpoints_need_a_login(anonymous, path):
    assert anonymous.get(path).status_code == 401


def test_stations_lists_the_configured_station_and_what_the_panel_hears(as_user):
    client = as_user("victor")
    deadline = time.monotonic() + 10
    while (st := client.get("/api/stations").json()[0])["relay"]["received"] == 0 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert st["name"] == "sim" and st["title"] == "Test station sim"
    assert st["relay"]["received"] > 0 and st["relay"]["silent_s"] < 2.0 and st["relay"]["malformed"] == 0


def test_status_and_library_come_from_the_station(as_user):
    client = as_user("victor")
    status = client.get("/api/stations/sim/status").json()
    assert status["busy"] is False and status["state"] in ("idle", "finished", "aborted")
    library = {p["name"]: p for p in client.get("/api/stations/sim/library").json()}
    params = {p["name"]: p for p in library["integral_precession"]["params"]}
    assert params["window_s"]["min"] == 1.0 and params["window_s"]["unit"] == "s"


def test_the_library_says_what_this_station_runs_and_where_the_rest_runs(as_user):
    """The embedded default station (vibration-sim) runs seed 000's procedures; the tumble, the shaker's, the two
    PIGAs' and the electronics' need another station file, named; labels are words with units, not code names."""
    library = {p["name"]: p for p in as_user("victor").get("/api/stations/sim/library").json()}
    assert library["integral_precession"]["not_here"] is None
    assert library["integral_precession.planning"]["not_here"] is None
    needs = {"tumble": "tumble-sim.toml", "rlg_g_sensitivity": "shaker-sim.toml", "multiposition": "dual-sim.toml",
             "nonlinear_suppression": "electronics-sim.toml"}  # fmt: skip
    for name, station_file in needs.items():
        files = library[name]["station_files"]
        assert station_file in files and "vibration-sim.toml" not in files, (name, files)
        assert "is not allowed" in library[name]["not_here"], library[name]["not_here"]
    labels = {p["name"]: p["label"] for p in library["integral_precession"]["params"]}
    assert labels["zs1_z0_sigma_m"] == "u(z0) of the Zs1 line fit (m)"
    assert labels["eps_f"] == "measured relative frequency error" and labels["window_s"] == "target window length (s)"
    assert all(label != name for name, label in labels.items())


@pytest.mark.parametrize(("name", "status"), [("nosuch", 404), ("bad name!", 422)])
def test_an_unknown_or_malformed_station_name(as_user, name, status):
    reply = as_user("victor").get(f"/api/stations/{name}/status")
    assert reply.status_code == status
    assert ("nosuch" in reply.json()["detail"]) if status == 404 else ("pattern" in reply.json()["detail"])


def test_the_websocket_refuses_anonymous_browsers(anonymous):
    with pytest.raises(WebSocketDisconnect) as closed, anonymous.websocket_connect("/ws/telemetry") as ws:
        ws.receive_text()
    assert closed.value.code == 4401


def test_the_websocket_refuses_another_sites_page(app_client, log_in):
    log_in(app_client, "victor")
    with (
        pytest.raises(WebSocketDisconnect) as closed,
        app_client.websocket_connect("/ws/telemetry", headers=browser_headers(app_client, "http://evil.example")) as ws,
    ):
        ws.receive_text()
    assert closed.value.code == 4403


def test_the_websocket_relays_the_status_beacon_at_5_per_second_in_order(app_client, log_in):
    log_in(app_client, "victor")
    docs: list[dict] = []
    with app_client.websocket_connect("/ws/telemetry?station=sim", headers=browser_headers(app_client)) as ws:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 3.0:
            docs += json.loads(ws.receive_text())
    status = [d for d in docs if d.get("topic") == "status"]
    relay = [d for d in docs if d.get("topic") == "relay"]
    assert len(status) >= (3.0 - 0.5) * STATUS_PER_S  # 0.5 s for connection and the first beacon
    seqs = [d["seq"] for d in status]
    assert seqs == sorted(seqs)
    assert all(d["station"] == "sim" and "state" in d["data"] for d in status)
    assert relay and relay[-1]["data"]["dropped"] == 0 and "sim" in relay[-1]["data"]["feeds"]


def test_a_websocket_for_another_station_gets_none_of_this_ones_telemetry(app_client, log_in):
    log_in(app_client, "victor")
    with app_client.websocket_connect("/ws/telemetry?station=other", headers=browser_headers(app_client)) as ws:
        first = json.loads(ws.receive_text())  # the first relay report comes at once
    assert [d["topic"] for d in first] == ["relay"] and first[0]["data"]["feeds"] == {}


def test_a_closed_websocket_leaves_no_queue_behind(app_client, log_in):
    log_in(app_client, "victor")
    before = app_client.get("/api/relay").json()
    with app_client.websocket_connect("/ws/telemetry", headers=browser_headers(app_client)) as ws:
        ws.receive_text()
        assert app_client.get("/api/relay").json()["browsers"] == before["browsers"] + 1
    deadline = time.monotonic() + 5
    while (now := app_client.get("/api/relay").json())["browsers"] != before["browsers"]:
        assert time.monotonic() < deadline, now
        time.sleep(0.05)
    assert now["dropped"] == before["dropped"] and now["queue_size"] > 0
