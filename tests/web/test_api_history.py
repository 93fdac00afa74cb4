"""History and gap diagnosis endpoints on sessions a real `station serve` recorded."""

from __future__ import annotations

import io
import re
import zipfile
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from station.control_channel import TOKEN_FILE, ControlClient, ensure_token
from web.archive import unpack

PROCEDURE = "integral_precession"
UNKNOWN = "20260101T000000-abcdef12"


@pytest.fixture(scope="module")
def recorded(station, quick) -> dict[str, str]:
    """A finished session (serial F-1) and an aborted one (serial A-2), recorded by the station."""
    client = ControlClient(station.control, token=ensure_token(station.out / TOKEN_FILE), timeout_s=20.0,
                           keys_dir=station.entry.telemetry_keys_dir())  # fmt: skip
    uids = {}
    try:
        for outcome, serial in (("finished", "F-1"), ("aborted", "A-2")):
            reply = client.request("start", {"procedure": PROCEDURE, "params": quick,
                                             "instrument_serial": serial}, user="fixture")  # fmt: skip
            assert reply["ok"], reply
            uids[outcome] = reply["result"]["session_uid"]
            if outcome == "aborted":
                client.request("abort", user="fixture")
            assert station.wait_until_idle()["state"] == outcome
    finally:
        client.close()
    return uids


@pytest.fixture(scope="module")
def victor(as_user) -> TestClient:
    return as_user("victor")


@pytest.fixture
def anonymous(app_client) -> TestClient:
    return TestClient(app_client.app, base_url="http://127.0.0.1")


def uids_of(client: TestClient, query: str = "") -> list[str]:
    reply = client.get(f"/api/sessions{query}")
    assert reply.status_code == 200, reply.text
    return [s["uid"] for s in reply.json()]


def test_sessions_need_a_login(anonymous):
    assert anonymous.get("/api/sessions").status_code == 401


def test_sessions_are_listed_newest_first_with_their_station(victor, recorded):
    rows = victor.get("/api/sessions").json()
    assert [r["uid"] for r in rows] == [recorded["aborted"], recorded["finished"]]
    assert rows[1]["n_points"] == 20 and rows[1]["status"] == "finished" and rows[1]["stations"] == ["sim"]


@pytest.mark.parametrize(
    ("query", "expected"),
    [
        ("?serial=f-", ["finished"]),
        ("?serial=nobody", []),
        ("?outcome=aborted", ["aborted"]),
        (f"?procedure={PROCEDURE}", ["aborted", "finished"]),
        ("?procedure=tumble", []),
        ("?station=sim&limit=1", ["aborted"]),
        ("?station=other", []),
    ],
)
def test_session_filters(victor, recorded, query, expected):
    assert uids_of(victor, query) == [recorded[o] for o in expected]


def test_date_filters(victor, recorded):
    today = datetime.now(UTC).date()
    assert len(uids_of(victor, f"?since={today}&until={today}")) == 2
    assert uids_of(victor, f"?since={today + timedelta(days=1)}") == []
    assert uids_of(victor, f"?until={today - timedelta(days=1)}") == []


@pytest.mark.parametrize(
    ("query", "words"),
    [
        ("?since=yesterday", ["query.since", "YYYY-MM-DD", "'yesterday'"]),
        ("?outcome=great", ["query.outcome", "'great'"]),
        ("?limit=0", ["query.limit", "greater than or equal to 1"]),
    ],
)
def test_bad_filters_are_422_naming_the_field(victor, query, words):
    reply = victor.get(f"/api/sessions{query}")
    assert reply.status_code == 422
    assert all(w in reply.json()["detail"] for w in words), reply.json()


def test_a_session_has_its_coefficients_with_uncertainties_points_and_events(victor, recorded):
    rec = victor.get(f"/api/sessions/{recorded['finished']}").json()
    assert rec["session"]["instrument_serial"] == "F-1" and rec["config"]["procedure"] == PROCEDURE
    integral = next(r["result"] for r in rec["results"] if r["method"] == "integral")
    kz = integral["coefficients"]["kz"]
    assert 0.5 < kz["value"] < 0.6 and 0 < kz["sigma"] < 1e-2  # the simulated PIGA's kz is 0.56 rad/s/g
    assert len(rec["points"]) == 20 and {"t1_s", "Tm_s", "t2_s", "Np"} <= set(rec["points"][0])
    assert any(e["message"].startswith("start by fixture") for e in rec["events"])


def test_residuals_by_vibration_point_for_both_methods(victor, recorded):
    res = victor.get(f"/api/sessions/{recorded['finished']}/residuals").json()
    assert set(res) == {"integral", "baseline"}
    assert len(res["integral"]["residuals_radps"]) == len(res["integral"]["point_ids"]) == 15
    assert max(map(abs, res["integral"]["residuals_radps"])) < 1e-4


def test_the_report_is_the_stations_self_contained_html(victor, recorded):
    reply = victor.get(f"/api/sessions/{recorded['finished']}/report")
    assert reply.status_code == 200 and reply.headers["content-type"].startswith("text/html")
    assert "Coefficients" in reply.text and "<svg" in reply.text
    assert 'src="http' not in reply.text and 'href="http' not in reply.text


def test_an_aborted_session_has_no_report_and_says_why(victor, recorded):
    reply = victor.get(f"/api/sessions/{recorded['aborted']}/report")
    assert reply.status_code in (404, 409)
    assert recorded["aborted"] in reply.json()["detail"]


def test_the_download_is_a_valid_piga_session_1_zip(victor, recorded, tmp_path: Path):
    reply = victor.get(f"/api/sessions/{recorded['finished']}/export")
    assert reply.status_code == 200 and reply.headers["content-type"] == "application/zip"
    assert f"session-{recorded['finished']}.zip" in reply.headers["content-disposition"]
    session = unpack(io.BytesIO(reply.content), tmp_path)
    assert len(session.points) == 20


@pytest.mark.parametrize("tail", ["", "/residuals", "/report", "/export", "/gap"])
def test_unknown_and_malformed_uids(victor, anonymous, tail):
    assert victor.get(f"/api/sessions/{UNKNOWN}{tail}").status_code == 404
    assert victor.get(f"/api/sessions/bad%20uid{tail}").status_code == 422
    assert anonymous.get(f"/api/sessions/{UNKNOWN}{tail}").status_code == 401


def test_gap_diagnosis_of_a_stored_session_and_its_html_report(victor, recorded):
    reply = victor.get(f"/api/sessions/{recorded['finished']}/gap")
    assert reply.status_code == 200, reply.text
    body = reply.json()
    assert body["id"] == f"session-{recorded['finished']}"
    report = body["report"]
    assert report["format"] == "piga-gap/1" and report["verdict"] in ("no_gap", "explained", "unexplained",
                                                                       "cannot_tell")  # fmt: skip
    assert report["where"]["maps"]["by_position"] and report["candidates"][0]["name"]
    kept = victor.get(f"/api/gap/{body['id']}").json()
    assert kept["report"]["verdict"] == report["verdict"]
    html = victor.get(f"/api/gap/{body['id']}/report")
    assert html.status_code == 200 and "Sim-to-real gap diagnosis" in html.text
    # It names the session it diagnosed (kept with it), and the panel says how long it took.
    row = victor.get(f"/api/sessions/{recorded['finished']}").json()["session"]
    named = {k: row[k] for k in ("uid", "procedure", "instrument_serial")} | {"n_points": report["session"]["n_points"]}
    assert {k: body["session"][k] for k in named} == named and kept["session"] == body["session"]
    status = victor.get("/api/gap/status").json()
    assert status["running"] is False and status["last_elapsed_s"] > 0
    assert not re.search(r"\d\.0*[1-9]\d{2,}", report["where"]["summary"]), report["where"]["summary"]  # levels rounded


def _zip(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


def test_gap_diagnosis_of_an_uploaded_session(victor, recorded):
    archive = victor.get(f"/api/sessions/{recorded['finished']}/export").content
    reply = victor.post("/api/gap", files={"archive": ("s.zip", archive, "application/zip")})
    assert reply.status_code == 200, reply.text
    assert reply.json()["id"].startswith("upload-") and reply.json()["report"]["session"]["n_points"] == 20


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"not a zip", ["not a zip archive"]),
        (_zip({"../evil/session.json": b"{}"}), ["outside the archive", "../evil/session.json"]),
        (_zip({"readme.txt": b"hi"}), ["one session.json"]),
        (_zip({"s/session.json": b"{", "s/points.csv": b""}), ["session.json"]),
    ],
)
def test_a_bad_upload_is_422_naming_the_defect(victor, content, words):
    reply = victor.post("/api/gap", files={"archive": ("s.zip", content, "application/zip")})
    assert reply.status_code == 422
    assert all(w in reply.json()["detail"] for w in words), reply.json()


def test_upload_needs_a_login_and_the_csrf_token(victor, anonymous):
    files = {"archive": ("s.zip", b"x", "application/zip")}
    assert anonymous.post("/api/gap", files=files).status_code == 401
    assert victor.post("/api/gap", files=files, headers={"X-CSRF-Token": "x"}).status_code == 403
    assert victor.post("/api/gap").status_code == 422


def test_unknown_gap_ids(victor, anonymous):
    assert victor.get("/api/gap/upload-0000/report").status_code == 404
    assert victor.get("/api/gap/nonsense").status_code == 422
    assert anonymous.get("/api/gap/upload-0000").status_code == 401
