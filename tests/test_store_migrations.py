"""Schema versioning of the store: ordered migrations to PRAGMA user_version, an upgrade of a store the previous
release wrote (tests/data/store-v2.sqlite, made by tests/data/make_store_v2.py from that release's store.py), and
a clear refusal of a store newer than the software."""

import shutil
import sqlite3
import subprocess
from pathlib import Path

import numpy as np
import pytest

from station.provenance import PROVENANCE_KEYS
from station.session import Measurement, StationInfo
from station.store import MIGRATIONS, SCHEMA_VERSION, SessionStore, StoreError

FIXTURE = Path(__file__).parent / "data" / "store-v2.sqlite"


def _user_version(path) -> int:
    with sqlite3.connect(path) as db:
        return db.execute("PRAGMA user_version").fetchone()[0]


def test_migrations_are_ordered_and_end_at_the_schema_version():
    versions = [m.version for m in MIGRATIONS]
    assert versions == list(range(1, len(versions) + 1)) and versions[-1] == SCHEMA_VERSION


def test_a_new_store_is_at_the_schema_version(tmp_path):
    with SessionStore(tmp_path / "db.sqlite") as store:
        assert store.schema_version == SCHEMA_VERSION
    assert _user_version(tmp_path / "db.sqlite") == SCHEMA_VERSION


def _previous_release_available() -> bool:
    from data.make_store_v2 import PREVIOUS_RELEASE

    probe = subprocess.run(["git", "-C", str(FIXTURE.parent), "cat-file", "-e", f"{PREVIOUS_RELEASE}^{{commit}}"],
                           capture_output=True)  # fmt: skip
    return probe.returncode == 0


@pytest.fixture(params=["committed fixture", "made now by the previous release's store.py"])
def old_store(request, tmp_path) -> Path:
    db = tmp_path / "old.sqlite"
    if request.param == "committed fixture":
        shutil.copy(FIXTURE, db)
        return db
    if not _previous_release_available():
        pytest.skip("no git history of the previous release in this checkout (shallow clone)")
    from data.make_store_v2 import make

    return make(db)


def test_a_store_of_the_previous_release_is_upgraded_with_everything_kept(old_store):
    db = old_store
    assert _user_version(db) == 0  # the previous release kept its version (2) in a table
    with SessionStore(db) as store:
        assert store.schema_version == SCHEMA_VERSION
        seed000, tumble = store.sessions()
        assert (seed000["n_points"], seed000["status"], seed000["instrument_serial"]) == (2, "finished", "PIGA-0042")
        assert tumble["n_measurements"] == 2
        s = store.load_session(seed000["uid"])
        assert s.station.latitude_deg == -33.92 and [p.Tm_s for p in s.points] == [560.84, 560.7]
        assert s.raw["P001-0deg-v10"].pulse_t.size == 80
        assert store.results(seed000["uid"])[0]["result"] == {"kz": 0.56}
        assert s.meta["params"] == {"positions_deg": [0.0]}
        # what the old store did not record is None, what it did is kept
        assert set(s.provenance) == set(PROVENANCE_KEYS) and s.provenance["instrument_serial"] == "PIGA-0042"
        assert s.provenance["station_id"] is None and s.provenance["software_version"] is None
        # record types inferred from the stored records: an int and a float in one field make a float64 field,
        # a field null in one record is nullable
        t = store.load_session(tumble["uid"])
        (rt,) = t.record_types
        assert rt.kind == "tumble" and rt.field("volts").dtype == "float64" and rt.field("J").dtype == "int64"
        assert rt.field("setup").nullable and rt.field("setup").dtype == "str"
        assert [m.values["volts"] for m in t.measurements] == [0.5, 1.25]
        assert t.measurements[0].arrays["volts"].shape == (4,)
        # and the upgraded store records new measurements through the inferred declaration, also where this
        # software declares the kind otherwise (seed 001's tumble): a session recorded before can be resumed
        import procedures.tumble.analysis  # noqa: F401 - declares "tumble"

        store.add_measurement(tumble["uid"], Measurement("T1-J3", "tumble", {"J": 3, "volts": 2, "samples": 9,
                                                                              "setup": "B"}))  # fmt: skip
        with pytest.raises(StoreError, match=r"field 'J' = 3\.5"):
            values = {"J": 3.5, "volts": 2.0, "samples": 9, "setup": None}
            store.add_measurement(tumble["uid"], Measurement("T1-J4", "tumble", values))
    with sqlite3.connect(db) as raw:
        assert (
            raw.execute("SELECT version FROM schema_version").fetchone()[0] == SCHEMA_VERSION
        )  # older software refuses it
    with SessionStore(db) as store:  # opening again migrates nothing
        assert len(store.sessions()) == 2


def test_a_store_newer_than_the_software_is_refused(tmp_path):
    db = tmp_path / "db.sqlite"
    with SessionStore(db) as store:
        store.create_session(StationInfo(), "test")
    with sqlite3.connect(db) as raw:
        raw.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    with pytest.raises(StoreError, match=rf"schema version {SCHEMA_VERSION + 1}, newer than this software reads "
                                         rf"\({SCHEMA_VERSION}\).*upgrade"):  # fmt: skip
        SessionStore(db)


def test_a_failed_migration_leaves_the_store_as_it_was(tmp_path, monkeypatch):
    db = tmp_path / "old.sqlite"
    shutil.copy(FIXTURE, db)
    import station.store as store_module

    def broken(conn):
        conn.execute("ALTER TABLE sessions ADD COLUMN half_done TEXT")
        raise RuntimeError("power cut")

    v3 = MIGRATIONS[2]
    assert v3.version == 3
    monkeypatch.setattr(store_module, "MIGRATIONS", (*MIGRATIONS[:2], type(v3)(3, v3.name, broken), *MIGRATIONS[3:]))
    with pytest.raises(RuntimeError, match="power cut"):
        store_module.SessionStore(db)
    with sqlite3.connect(db) as raw:
        columns = [r[1] for r in raw.execute("PRAGMA table_info(sessions)")]
        assert "half_done" not in columns and "provenance_json" not in columns
        assert raw.execute("SELECT version FROM schema_version").fetchone()[0] == 2
    monkeypatch.undo()
    with SessionStore(db) as store:  # the real migration still applies afterwards
        assert store.schema_version == SCHEMA_VERSION
        assert np.isclose(store.load_session(store.sessions()[0]["uid"]).points[1].Tm_s, 560.7)


def test_a_session_keeps_the_declaration_its_records_were_stored_with(tmp_path):
    from station.records import Field, RecordType

    v1 = RecordType("probe", (Field("level_v", "float64", "V"),))
    v2 = RecordType("probe", (Field("level_v", "float64", "mV"),))  # the same name, another unit
    with SessionStore(tmp_path / "db.sqlite") as store:
        uid = store.create_session(StationInfo(), "test")
        store.add_measurement(uid, Measurement("m1", "probe", {"level_v": 1}), v1)
        with pytest.raises(StoreError, match="declares it otherwise than the session holds it"):
            store.add_measurement(uid, Measurement("m2", "probe", {"level_v": 2.0}), v2)
        (m1,) = store.measurements(uid)
        assert m1.values == {"level_v": 1.0} and type(m1.values["level_v"]) is float  # typed by the declaration
        assert store.record_types(uid) == [v1]
