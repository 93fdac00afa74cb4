"""Every procedure's session survives the round trip: recorded through the simulated station (engine, drivers,
emulators), exported as piga-session/1, imported into a fresh store: the same store content (points, raw streams,
typed measurements and their arrays, record types, provenance, results, procedure and parameters).

Short parameters keep each session to a few seconds of wall time (all of them about a minute on 2 cores)."""

import json
from pathlib import Path

import numpy as np
import pytest
from procedure_runs import CONFIG, RUNS, record

from drivers.config import load_station_config
from station.interchange import (
    TIMING_DEFAULTS,
    SessionFormatError,
    content_hash,
    frequency_error,
    read_session,
    write_session,
)
from station.provenance import PROVENANCE_KEYS
from station.store import SessionStore
from station.twin.config import default_twin


def test_every_procedure_file_is_covered():
    assert sorted(RUNS) == sorted(p.stem for p in (CONFIG / "procedures").glob("*.toml"))


def _record(name: str, db: Path) -> str:
    uid = record(name, db)
    with SessionStore(db) as store:
        store.add_result(uid, "round-trip", {"kz": 0.56, "names": ["kz"]})
    return uid


def _same_arrays(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("name", sorted(RUNS))
def test_export_then_import_gives_the_same_store_content(tmp_path, name):
    uid = _record(name, tmp_path / "station.sqlite")
    with SessionStore(tmp_path / "station.sqlite") as store:
        before = store.load_session(uid)
        (row,) = store.sessions()
    exported = write_session(before, tmp_path / "export")
    with SessionStore(tmp_path / "other.sqlite") as other:
        new_uid, created = other.import_session(read_session(exported), content_hash(read_session(exported)))
        assert created
        again = other.import_session(read_session(exported), content_hash(read_session(exported)))
        assert again == (new_uid, False)  # the same content is recognised, not stored twice
        after = other.load_session(new_uid)
        (new_row,) = other.sessions()
    assert (new_row["procedure"], new_row["n_points"], new_row["n_measurements"], new_row["status"]) == (
        row["procedure"], row["n_points"], row["n_measurements"], "imported"
    )  # fmt: skip
    assert after.station == before.station and after.notes == before.notes
    assert after.points == before.points
    assert sorted(after.raw) == sorted(before.raw)
    for pid in before.raw:
        _same_arrays(vars(after.raw[pid]), vars(before.raw[pid]))
    assert [rt.to_json() for rt in after.record_types] == [rt.to_json() for rt in before.record_types]
    assert [(m.key, m.kind, m.values) for m in after.measurements] == [
        (m.key, m.kind, m.values) for m in before.measurements
    ]
    for a, b in zip(after.measurements, before.measurements, strict=True):
        _same_arrays(a.arrays, b.arrays)
    assert after.provenance == before.provenance
    assert set(before.provenance) >= set(PROVENANCE_KEYS)
    station_id = load_station_config(CONFIG / "stations" / f"{RUNS[name][0]}.toml").station_id
    assert before.provenance["station_id"] == station_id and before.provenance["simulated"] is True
    assert before.provenance["seed"] == 11 and before.provenance["instrument_serial"] == "PIGA-RT-1"
    assert [r["result"] for r in after.results] == [r["result"] for r in before.results]
    for key in ("procedure", "params", "instrument_serial"):
        assert after.meta[key] == before.meta[key], key
    # every measurement is typed by its kind's declaration (ints stay ints, floats floats)
    types = {rt.kind: rt for rt in before.record_types}
    for m in before.measurements:
        for f in types[m.kind].fields:
            v = m.values.get(f.name)
            if v is not None and f.ndim == 0:
                assert type(v) is {"float64": float, "int64": int, "str": str, "bool": bool}[f.dtype], (m.key, f.name)


def test_a_session_whose_table_ran_3e_4_off_frequency_exports_and_imports_again(tmp_path):
    """The engine accepts a frequency error up to 5e-4 (station.engine.timing.FREQ_TOLERANCE_REL, Table 4) where an
    import
    assumes 1e-4 unless session.json states more: the export states what the points show (rounded up to two
    digits), so the import's Np check passes them, and still refuses an Np one period off."""
    eps_f = 3e-4
    twin = default_twin().with_effect("frequency_error", eps_f=eps_f)
    uid = record("integral_precession", tmp_path / "station.sqlite", twin=twin)
    with SessionStore(tmp_path / "station.sqlite") as store:
        before = store.load_session(uid)
    shown = frequency_error(before.points)
    assert 0.9 * eps_f < shown < 1.1 * eps_f  # the points show the table's error (to 10 %, the stamps' noise)
    assert shown > TIMING_DEFAULTS["frequency_stability"]  # what an import would refuse without the statement
    exported = write_session(before, tmp_path / "export")
    with SessionStore(tmp_path / "other.sqlite") as other:
        new_uid, created = other.import_session(read_session(exported), content_hash(read_session(exported)))
        assert created and other.load_session(new_uid).points == before.points
    stated = json.loads((exported / "session.json").read_text())["timing"]["frequency_stability"]
    assert shown <= stated <= 1.1 * shown
    # the statement loosens the check to what the points need, no more: Np one period off is still refused
    csv = exported / "points.csv"
    rows = csv.read_text().splitlines()
    header = rows[0].split(",")
    i = next(n for n, r in enumerate(rows[1:], 1) if r.split(",")[header.index("kind")] == "vibration")
    cells = rows[i].split(",")
    cells[header.index("Np")] = str(int(cells[header.index("Np")]) + 1)
    csv.write_text("\n".join([*rows[:i], ",".join(cells), *rows[i + 1 :]]) + "\n")
    with pytest.raises(SessionFormatError, match="Np"):
        read_session(exported)


def test_an_export_states_the_default_stability_when_the_points_need_less(tmp_path):
    uid = record("integral_precession.integer_periodic_vibration", tmp_path / "station.sqlite")
    with SessionStore(tmp_path / "station.sqlite") as store:
        session = store.load_session(uid)
    assert frequency_error(session.points) < TIMING_DEFAULTS["frequency_stability"]
    doc = json.loads((write_session(session, tmp_path / "export") / "session.json").read_text())
    assert doc["timing"] == {"frequency_stability": TIMING_DEFAULTS["frequency_stability"]}
