"""The panel's history read from the central database answers as it does from the stations' SQLite stores."""

from __future__ import annotations

import re
import sqlite3
from datetime import date
from pathlib import Path

import pytest
from fastapi import HTTPException
from fastapi.testclient import TestClient
from pydantic import ValidationError

from station.central.sync import open_central, sync_store
from station.store import SessionStore
from web.app import create_app
from web.config import CentralEntry, PanelConfig, StationEntry
from web.history import History, SessionFilter
from web.users import UserBook

STATUSES = ("finished", "aborted", "finished", "imported", "running", "finished")
DAYS = ("2026-03-01", "2026-03-02", "2026-03-02", "2026-04-10", "2026-05-01", "2026-05-03")


@pytest.fixture(scope="module")
def two_histories(tmp_path_factory, database, fill):
    """The same sessions read from a station's store and from the central database they were synced to."""
    tmp_path, central_url = tmp_path_factory.mktemp("panel"), database()
    arrays_dir = tmp_path / "arrays"
    db = tmp_path / "station.sqlite"
    with SessionStore(db) as store:
        uids = fill(store, STATUSES[:1], serial="PIGA-{k}{k}", n_points=40)  # identifiable: it has a report
        uids += fill(store, STATUSES[1:], serial="PIGA-{k}{k}", first=1)
    with sqlite3.connect(db) as conn:  # sessions of several days, as a station's history has
        for k, (uid, day) in enumerate(zip(uids, DAYS, strict=True)):
            conn.execute("UPDATE sessions SET created_utc = ? WHERE uid = ?", (f"{day}T10:0{k}:00.000+00:00", uid))
        conn.execute("UPDATE sessions SET procedure = 'integral_precession.self_alignment' WHERE uid = ?", (uids[1],))
        # stored by an earlier version, under the procedure's former name (station.procedure_names)
        conn.execute("UPDATE sessions SET procedure = 'seed000.self_alignment' WHERE uid = ?", (uids[3],))
    with SessionStore(db) as store:
        engine = open_central(central_url)
        sync_store(store, engine, arrays_dir, "sim")
        engine.dispose()
    entry = StationEntry(name="sim", control="tcp://127.0.0.1:1", telemetry="tcp://127.0.0.1:2", store=db,
                         reports=tmp_path / "reports")  # fmt: skip
    where = CentralEntry(url=central_url, arrays=arrays_dir)
    local, central = History([entry]), History([entry], where)
    yield local, central, uids, PanelConfig(users=users(tmp_path / "users.json"), audit_log=tmp_path / "audit.jsonl",
                                            stations=(entry,), central=where)  # fmt: skip
    local.close()
    central.close()


def users(path: Path) -> Path:
    UserBook(path).add("victor", "viewer", "viewer-pass-1")
    return path


FILTERS = [
    SessionFilter(),
    SessionFilter(serial="iga-3"),
    SessionFilter(serial="%"),  # a LIKE wildcard is a character like any other
    SessionFilter(procedure="integral_precession.self_alignment"),
    SessionFilter(procedure="seed000.self_alignment"),
    SessionFilter(outcome="finished"),
    SessionFilter(since=date(2026, 3, 2), until=date(2026, 4, 10)),
    SessionFilter(until=date(2026, 3, 1)),
    SessionFilter(station="sim", outcome="aborted"),
    SessionFilter(station="other"),
]


@pytest.mark.parametrize("where", FILTERS, ids=[repr(f) for f in FILTERS])
def test_the_listing_is_the_same_from_either(two_histories, where):
    local, central, uids, _ = two_histories
    ended = {u for u, s in zip(uids, STATUSES, strict=True) if s != "running"}  # a running one is not synced
    expected = [r for r in local.sessions(where, 100) if r["uid"] in ended]
    assert central.sessions(where, 100) == expected
    assert central.sessions(where, 2) == expected[:2]


@pytest.mark.parametrize("name", ["integral_precession.self_alignment", "seed000.self_alignment"])
def test_a_procedure_lists_its_sessions_stored_under_either_name(two_histories, name):
    local, central, uids, _ = two_histories
    for history in (local, central):
        assert [r["uid"] for r in history.sessions(SessionFilter(procedure=name), 100)] == [uids[3], uids[1]]


def test_session_page_report_and_gap_inputs_are_the_same_from_either(two_histories):
    local, central, uids, _ = two_histories
    uid = uids[0]
    assert central.row(uid) == local.row(uid)
    assert central.record(uid) == local.record(uid)
    a, b = local.load(uid, with_raw=True), central.load(uid, with_raw=True)  # what the gap page diagnoses
    assert b.points == a.points and sorted(b.raw) == sorted(a.raw)
    text = [re.sub(r"<svg.*?</svg>", "", h.report_html(uid), flags=re.DOTALL) for h in (central, local)]
    assert "<table" in text[0] and text[0] == text[1]  # the procedure's analysis of the stored session, figures apart
    with pytest.raises(HTTPException) as missing:
        central.record(uids[4])  # still running at the station: not in the central history
    assert missing.value.status_code == 404 and "central history" in missing.value.detail


def test_the_panel_file_names_the_central_database_without_its_password(tmp_path):
    toml = tmp_path / "panel.toml"
    station = '[[stations]]\nname = "a"\ncontrol = "tcp://h:1"\ntelemetry = "tcp://h:2"\nstore = "s"\nreports = "r"\n'
    toml.write_text(f'[central]\nurl = "postgresql://panel@db.lab/history"\narrays = "/lab/arrays"\n{station}')
    config = PanelConfig.from_toml(toml)
    assert config.central == CentralEntry(url="postgresql://panel@db.lab/history", arrays=Path("/lab/arrays"))
    with pytest.raises(ValidationError, match="password"):
        CentralEntry(url="postgresql://panel:secret@db.lab/history", arrays=Path("/lab/arrays"))
    with pytest.raises(ValidationError, match="postgresql"):
        CentralEntry(url="sqlite:///history.db", arrays=Path("/lab/arrays"))


def test_the_panel_serves_the_central_history(two_histories):
    local, _, uids, config = two_histories
    with TestClient(create_app(config), base_url="http://127.0.0.1") as client:
        reply = client.post("/api/login", json={"username": "victor", "password": "viewer-pass-1"})
        assert reply.status_code == 200, reply.text
        listing = client.get("/api/sessions", params={"outcome": "finished", "since": "2026-03-02"})
        assert listing.status_code == 200, listing.text
        assert [r["uid"] for r in listing.json()] == [uids[5], uids[2]]  # newest first, from the database
        page = client.get(f"/api/sessions/{uids[2]}")
        assert page.status_code == 200 and page.json()["points"] == local.record(uids[2])["points"]
        assert client.get(f"/api/sessions/{uids[4]}").status_code == 404  # running: not synced yet
        export = client.get(f"/api/sessions/{uids[0]}/export")
        assert export.status_code == 200 and export.headers["content-type"] == "application/zip"
