"""Control through the panel against a real `station serve`: roles, CSRF, 422 messages, the run's life and its audit."""

from __future__ import annotations

import json
import time

import pytest
from fastapi.testclient import TestClient

ACTIONS = ("pause", "resume", "abort", "estop", "reset")
PROCEDURE = "integral_precession"
STATE_TIMEOUT_S = 30.0
FINAL = ("finished", "aborted", "estopped", "failed")


@pytest.fixture
def anonymous(app_client) -> TestClient:
    return TestClient(app_client.app, base_url="http://127.0.0.1")


@pytest.fixture(scope="module")
def olga(as_user) -> TestClient:
    return as_user("olga")


@pytest.fixture(scope="module")
def victor(as_user) -> TestClient:
    return as_user("victor")


def start_body(quick: dict, **params) -> dict:
    return {"procedure": PROCEDURE, "params": quick | params, "instrument_serial": "PIGA-T-42"}


def wait_for(client: TestClient, states: tuple[str, ...], timeout_s: float = STATE_TIMEOUT_S, idle=False) -> dict:
    """The station's status once its state is one of `states` (and, with idle, its analysis is done too)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status = client.get("/api/stations/sim/status").json()
        if status["state"] in states and not (idle and status["busy"]):
            return status
        time.sleep(0.05)
    raise AssertionError(f"state {status['state']!r} after {timeout_s} s, expected one of {states}")


@pytest.mark.parametrize("action", [*ACTIONS, "start", "plan", "resume-session"])
def test_control_needs_a_login(anonymous, quick, action):
    reply = anonymous.post(f"/api/stations/sim/{action}", json=start_body(quick))
    assert reply.status_code == 401


@pytest.mark.parametrize("action", [*ACTIONS, "start", "resume-session"])
def test_viewers_may_not_control(victor, quick, action):
    body = {"uid": "20260101T000000-abcdef12"} if action == "resume-session" else start_body(quick)
    reply = victor.post(f"/api/stations/sim/{action}", json=body)
    assert reply.status_code == 403
    assert reply.json()["detail"] == "operators only: victor is a viewer"


@pytest.mark.parametrize("action", [*ACTIONS, "start"])
def test_an_operator_without_the_csrf_token_may_not_control(olga, quick, action):
    reply = olga.post(f"/api/stations/sim/{action}", json=start_body(quick), headers={"X-CSRF-Token": ""})
    assert reply.status_code == 403 and "CSRF" in reply.json()["detail"]


def test_a_viewer_may_dry_run(victor, quick):
    reply = victor.post("/api/stations/sim/plan", json={"procedure": PROCEDURE, "params": quick})
    assert reply.status_code == 200
    plan = reply.json()
    assert plan["n_measurements"] == 20 and 500 < plan["total_s"] < 2000


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"params": {"window_s": 0}}, ["window_s", "= 0", "allowed float in [1, 100000] s"]),
        ({"params": {"freqs_hz": [8, 12]}}, ["freqs_hz", "12", "[0.1, 10] Hz"]),
        ({"params": {"positions_deg": []}}, ["positions_deg", "non-empty"]),
        ({"params": {"window": 30}}, ["unknown parameter", "'window'", "allowed: positions_deg"]),
        ({"params": {"raw": "yes"}}, ["raw", "'yes'", "true or false"]),
        ({"procedure": "seed000.nosuch"}, ["unknown procedure", "seed000.nosuch", "integral_precession"]),
        ({"params": {"window_s": {"a": 1}}}, ["body.params.window_s"]),
        ({"params": {"window_s": 10**30}}, ["body.params.window_s"]),
        ({"instrument_serial": "bad\nserial"}, ["body.instrument_serial", "pattern"]),
        ({"extra": 1}, ["body.extra", "Extra inputs are not permitted"]),
        ({"procedure": ""}, ["body.procedure", "at least 1 character"]),
    ],
)
def test_bad_input_is_422_with_a_message_naming_field_value_and_what_is_allowed(olga, quick, change, words):
    body = start_body(quick)
    body |= {k: (body["params"] | v if k == "params" else v) for k, v in change.items()}
    plan = {k: v for k, v in body.items() if k != "instrument_serial"}
    for action, sent in (("plan", plan), ("start", body)) if "instrument_serial" not in change else (("start", body),):
        reply = olga.post(f"/api/stations/sim/{action}", json=sent)
        assert reply.status_code == 422, reply.text
        detail = reply.json()["detail"]
        assert all(w in detail for w in words), detail


def test_unknown_station_is_404(olga):
    assert olga.post("/api/stations/nosuch/pause").status_code == 404


def test_start_pause_resume_abort_resume_session_with_audit_and_the_stations_event_log(olga, quick, panel_config):
    started = olga.post("/api/stations/sim/start", json=start_body(quick))
    assert started.status_code == 200, started.text
    uid = started.json()["result"]["session_uid"]
    assert olga.post("/api/stations/sim/pause").status_code == 200
    paused = wait_for(olga, ("paused",))
    time.sleep(0.5)
    assert olga.get("/api/stations/sim/status").json()["done"] == paused["done"]  # nothing measured while paused
    again = olga.post("/api/stations/sim/start", json=start_body(quick))
    assert again.status_code == 409 and "already running" in again.json()["detail"]
    assert olga.post("/api/stations/sim/resume").status_code == 200
    assert olga.get("/api/stations/sim/status").json()["state"] == "running"
    assert olga.post("/api/stations/sim/abort").status_code == 200
    aborted = wait_for(olga, ("aborted", "finished"))
    assert aborted["state"] == "aborted", "the quick session ended before the abort: abort untested"

    resumed = olga.post("/api/stations/sim/resume-session", json={"uid": uid})
    assert resumed.status_code == 200 and resumed.json()["result"]["session_uid"] == uid
    wait_for(olga, ("finished",), timeout_s=60, idle=True)

    finished = olga.post("/api/stations/sim/resume-session", json={"uid": uid})
    assert finished.status_code == 409 and "finished" in finished.json()["detail"]
    unknown = olga.post("/api/stations/sim/resume-session", json={"uid": "20260101T000000-abcdef12"})
    assert unknown.status_code == 404
    assert olga.post("/api/stations/sim/resume-session", json={"uid": "../x"}).status_code == 422

    audit = [json.loads(line) for line in panel_config.audit_log.read_text().splitlines()]
    mine = [(a["action"], a["ok"]) for a in audit if a["user"] == "olga" and a["action"] != "login"]
    for step in [("start", True), ("pause", True), ("start", False), ("resume", True), ("abort", True),
                 ("resume_session", True)]:  # fmt: skip
        assert step in mine
    assert all("t_utc" in a for a in audit)
    events = [e["message"] for e in olga.get(f"/api/sessions/{uid}").json()["events"] if e["kind"] == "control"]
    assert [e.split(" {")[0] for e in events] == [
        "start by olga via panel", "pause by olga via panel", "resume by olga via panel", "abort by olga via panel",
        "resume_session by olga via panel",
    ]  # fmt: skip


def test_emergency_stop_ends_the_run(olga, quick):
    started = olga.post("/api/stations/sim/start", json=start_body(quick, window_s=200))
    assert started.status_code == 200
    uid = started.json()["result"]["session_uid"]
    time.sleep(1.0)  # into the first window
    assert olga.post("/api/stations/sim/estop").status_code == 200
    status = wait_for(olga, FINAL, timeout_s=10, idle=True)
    events = olga.get(f"/api/sessions/{uid}").json()["events"]
    assert status["state"] == "estopped", events
    assert status["freq_hz"] == 0.0 and status["busy"] is False and status["head_held"] is True
    assert any(e["message"] == "estop by olga via panel" for e in events)
    # The head stays held until an operator resets the station (once the cause is removed).
    assert olga.post("/api/stations/sim/reset").status_code == 200
    status = olga.get("/api/stations/sim/status").json()
    assert status["head_held"] is False and status["drive_fault"] is None


def test_the_audit_log_is_readable_by_viewers_not_anonymous(victor, anonymous):
    entries = victor.get("/api/audit?limit=5").json()
    assert 0 < len(entries) <= 5 and all({"t_utc", "user", "action"} <= set(e) for e in entries)
    assert anonymous.get("/api/audit").status_code == 401
    assert victor.get("/api/audit?limit=0").status_code == 422
