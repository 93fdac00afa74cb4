"""`station import`: the whole directory validated first, then one transaction; the same content twice is one
session; BOMs, CRLF, duplicate columns, station keys and ranges handled as the station file does."""

import csv
import json

import numpy as np
import pytest
from session_files import set_cell

from station.cli.cli import main
from station.interchange import SessionFormatError, content_hash, read_session, write_session
from station.provenance import PROVENANCE_KEYS
from station.records import Field, RecordType
from station.session import Measurement
from station.store import SessionStore, StoreError
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session


@pytest.fixture(scope="module")
def session():
    plan = multiposition_plan([0.0, 60.0, 180.0], [9.0, 10.0], window_s=20.0)  # 9 points: 6 vibration, 3 static
    return simulate_session(plan, TwinConfig(), seed=5)


@pytest.fixture
def session_dir(tmp_path, session):
    return write_session(session, tmp_path / "s")


def _import(session_dir, db) -> int:
    return main(["import", str(session_dir), "--db", str(db)])


def _sessions(db) -> list[dict]:
    with SessionStore(db) as store:
        return store.sessions()


def _set_station(session_dir, **keys) -> None:
    path = session_dir / "session.json"
    doc = json.loads(path.read_text())
    doc["station"] |= keys
    path.write_text(json.dumps(doc))


def test_the_same_content_twice_is_one_session(tmp_path, session_dir, capsys):
    db = tmp_path / "db.sqlite"
    assert _import(session_dir, db) == 0
    assert _import(session_dir, db) == 0
    assert "already imported" in capsys.readouterr().out
    (only,) = _sessions(db)
    assert only["n_points"] == 9 and only["status"] == "imported"


def test_bom_and_crlf_are_the_same_content(tmp_path, session_dir, session):
    for name in ("points.csv", "session.json"):
        path = session_dir / name
        text = path.read_text().replace("\r\n", "\n").replace("\n", "\r\n")
        path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    back = read_session(session_dir)
    assert back.points == session.points
    assert content_hash(back) == content_hash(session)  # so a re-import of the converted copy is recognised
    db = tmp_path / "db.sqlite"
    write_session(session, tmp_path / "plain")
    assert _import(tmp_path / "plain", db) == 0 and _import(session_dir, db) == 0
    assert len(_sessions(db)) == 1


def test_a_duplicate_sequence_on_the_fifth_point_stores_nothing(tmp_path, session_dir):
    db = tmp_path / "db.sqlite"
    set_cell(session_dir, 6, "sequence", "0")  # row 6 = the fifth point
    with pytest.raises(SessionFormatError, match=r"points\.csv row 6, column 'sequence', value '0'.*duplicate"):
        read_session(session_dir)
    assert _import(session_dir, db) == 2
    assert _sessions(db) == []


def test_an_overflow_leaves_no_empty_session(tmp_path, session_dir):
    db = tmp_path / "db.sqlite"
    set_cell(session_dir, 9, "pulses", str(2**70))  # beyond what the counter (and SQLite's INTEGER) can hold
    assert _import(session_dir, db) == 2
    assert _sessions(db) == []


def test_a_store_side_refusal_rolls_the_whole_import_back(tmp_path, session):
    """A measurement the store refuses (its values break the declaration) after every point was written."""
    rt = RecordType("probe", (Field("level_v", "float64", "V", lo=0.0, hi=10.0),))
    bad = type(session)(session.station, session.points, measurements=[Measurement("m1", "probe", {"level_v": 11.0})],
                        record_types=[rt])  # fmt: skip
    with SessionStore(tmp_path / "db.sqlite") as store:
        with pytest.raises(StoreError, match=r"measurement 'm1' \(probe\): field 'level_v' = 11\.0.*\[0, 10\] \(V\)"):
            store.import_session(bad, content_hash(bad))
        assert store.sessions() == []


def test_a_column_named_twice_is_refused(session_dir):
    path = session_dir / "points.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0] + ",pulses", *(line + ",1" for line in lines[1:])]) + "\n")
    with pytest.raises(SessionFormatError, match=r"points\.csv row 1, column 'pulses': column named twice"):
        read_session(session_dir)


@pytest.mark.parametrize(
    ("key", "value", "allowed"),
    [
        ("latitude_deg", 400.0, r"\[-90, 90\] \(deg\)"),
        ("g_mps2", 1e6, r"\[9\.7, 9\.9\]"),
        ("pulses_per_rev", 16384.5, "whole number"),
        ("A0_m", True, "finite number"),
    ],
)
def test_station_keys_are_checked_as_the_station_file_does(session_dir, key, value, allowed):
    _set_station(session_dir, **{key: value})
    with pytest.raises(SessionFormatError, match=rf"session\.json, column 'station\.{key}', value .*{allowed}"):
        read_session(session_dir)


def test_a_southern_station_imports_its_own_export(tmp_path, session_dir):
    _set_station(session_dir, latitude_deg=-33.92)  # the station file allows -90 .. 90, so does the import
    db = tmp_path / "db.sqlite"
    assert _import(session_dir, db) == 0
    with SessionStore(db) as store:
        (s,) = store.sessions()
        back = store.load_session(s["uid"])
    assert back.station.latitude_deg == -33.92
    write_session(back, tmp_path / "again")
    assert read_session(tmp_path / "again").station.latitude_deg == -33.92


def test_a_directory_with_only_the_physics_md_fields_imports(tmp_path, session):
    d = tmp_path / "bare"
    d.mkdir()
    st = session.station
    keys = ("A0_m", "latitude_deg", "g_mps2", "earth_rate_radps", "pulses_per_rev")
    doc = {"format": "piga-session/1", "station": {k: getattr(st, k) for k in keys}, "notes": "from another lab"}
    (d / "session.json").write_text(json.dumps(doc))
    with (d / "points.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["point_id", "sequence", "start_s", "position_deg", "freq_hz", "kind", "pulses", "Tm_s", "t1_s",
                    "t2_s", "Np"])  # fmt: skip
        for p in session.points:
            w.writerow([p.point_id, p.sequence, p.start_s, p.position_deg, p.freq_hz, p.kind, p.pulses, p.Tm_s,
                        "" if p.t1_s is None else p.t1_s, "" if p.t2_s is None else p.t2_s,
                        "" if p.Np is None else p.Np])  # fmt: skip
    db = tmp_path / "db.sqlite"
    assert _import(d, db) == 0
    with SessionStore(db) as store:
        (s,) = store.sessions()
        back = store.load_session(s["uid"])
    assert back.points == session.points and back.notes == "from another lab"
    assert set(back.provenance) == set(PROVENANCE_KEYS) and all(v is None for v in back.provenance.values())


def test_measurement_cells_name_file_row_column_value_allowed(tmp_path, session):
    rt = RecordType("probe", (Field("level_v", "float64", "V", lo=0.0, hi=10.0), Field("n", "int64")),
                    arrays=(Field("trace_v", "float64", "V"),))  # fmt: skip
    s = type(session)(session.station, [], measurements=[
        Measurement("m1", "probe", {"level_v": 1.5, "n": 3}, {"trace_v": np.arange(4.0)}),
        Measurement("m2", "probe", {"level_v": 2.5, "n": 4}),
    ], record_types=[rt])  # fmt: skip
    d = write_session(s, tmp_path / "m")
    back = read_session(d)
    assert [m.values for m in back.measurements] == [{"level_v": 1.5, "n": 3}, {"level_v": 2.5, "n": 4}]
    np.testing.assert_array_equal(back.measurements[0].arrays["trace_v"], np.arange(4.0))
    path = d / "measurements" / "probe.csv"
    path.write_text(path.read_text().replace(",2.5,4,", ",12.5,4,"))
    with pytest.raises(SessionFormatError, match=r"measurements/probe\.csv row 3, column 'level_v', value '12\.5'"
                                                 r": must be a finite number in \[0, 10\] \(V\)"):  # fmt: skip
        read_session(d)


def test_an_import_keeps_the_uid_of_the_export(tmp_path, session, capsys):
    with SessionStore(tmp_path / "a.sqlite") as a:
        uid, _ = a.import_session(session, content_hash(session))
        exported = write_session(a.load_session(uid), tmp_path / "export")
    assert json.loads((exported / "session.json").read_text())["store_uid"] == uid
    db = tmp_path / "b.sqlite"
    assert _import(exported, db) == 0
    assert capsys.readouterr().out.rstrip().endswith(f"as session {uid}")  # its certificate's uid is found here
    assert _import(exported, db) == 0  # the same uid and content again: nothing stored
    assert f"already imported: the same content is session {uid}" in capsys.readouterr().out
    assert [s["uid"] for s in _sessions(db)] == [uid]
    doc = json.loads((exported / "session.json").read_text())
    _set_station(exported, latitude_deg=doc["station"]["latitude_deg"] + 0.01)  # other content, the same uid
    assert _import(exported, db) == 2  # other content under a uid the store holds: refused, nothing stored
    assert f"session {uid} is already in" in capsys.readouterr().err
    assert [s["uid"] for s in _sessions(db)] == [uid]
    (exported / "session.json").write_text(json.dumps({**doc, "store_uid": "../../etc"}))
    with pytest.raises(SessionFormatError, match="store_uid"):
        read_session(exported)
