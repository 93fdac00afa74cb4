"""piga-session/1 import and export: exact round trip, and every malformed input refused clearly."""

import json

import h5py
import numpy as np
import pytest
from session_files import set_cell

from station.cli.cli import main
from station.interchange import SessionFormatError, read_session, write_session
from station.store import SessionStore
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session


@pytest.fixture(scope="module")
def session():
    # 20 s windows keep the raw streams small (5 kHz grating, ~12k pulse edges per second at 10 Hz)
    plan = multiposition_plan([0.0, 60.0, 180.0], [9.0, 10.0], window_s=20.0)
    return simulate_session(plan, TwinConfig(), seed=5, raw=True)


@pytest.fixture
def session_dir(tmp_path, session):
    return write_session(session, tmp_path / "s")


def test_round_trip_is_exact(session, session_dir):
    back = read_session(session_dir)
    assert back.points == session.points
    assert back.station == session.station
    for pid, raw in session.raw.items():
        np.testing.assert_array_equal(back.raw[pid].pulse_t, raw.pulse_t)
        np.testing.assert_array_equal(back.raw[pid].grating_z, raw.grating_z)


# row 2 is the first vibration point (0 deg, 9 Hz); row 4 the static point at 0 deg
BAD_CELLS = [
    (2, "kind", "vibrating", "kind must be 'static' or 'vibration'"),
    (2, "Tm_s", "nan", "finite number"),
    (2, "Tm_s", "-560.1", r"must be a finite number in \(0, 1e\+06\] \(s\)"),
    (2, "start_s", "-5", r"must be a finite number in \[0, "),
    (2, "freq_hz", "1000", r"in \[0, 100\] \(Hz\)"),  # above any table's frequency (station file: <= 100 Hz)
    (2, "position_deg", "7200", r"in \[-720, 720\] \(deg\)"),  # beyond the indexing head's travel
    (2, "sequence", "-1", r"a whole number in \[0, "),
    (3, "sequence", "0", r"duplicate sequence \(first on row 2\)"),
    (2, "t2_s", "0.2", r"t2_s must lie in \[0, T\)"),
    (2, "t1_s", "abc", "expected a number"),
    (2, "Np", "12.5", "whole number"),
    (2, "Np", "4000", r"t1 \+ Np T - Tm - t2 = .* Np is not the whole periods"),
    (2, "pulses", "0", "non-zero"),
    (2, "freq_hz", "0", r"vibration point needs freq_hz in \[0\.001, 100\] Hz"),
    (2, "freq_hz", "5e-324", r"vibration point needs freq_hz in \[0\.001, 100\] Hz"),  # an infinite period
    (2, "freq_hz", "1e-320", r"vibration point needs freq_hz in \[0\.001, 100\] Hz"),
    (2, "point_id", "../../etc/passwd", "point_id must be 1-128 letters, digits"),
    (2, "point_id", "<script>alert(1)</script>", "point_id must be 1-128 letters, digits"),
    (4, "t1_s", "0.01", "must be empty for a static point"),
    (4, "freq_hz", "10", "static point must have freq_hz = 0"),
    (3, "point_id", "P001-0deg-v9", "duplicate point_id"),
]


@pytest.mark.parametrize(("row", "column", "value", "message"), BAD_CELLS)
def test_malformed_cell_names_file_row_column_value(session_dir, row, column, value, message):
    set_cell(session_dir, row, column, value)
    with pytest.raises(SessionFormatError, match=message) as info:
        read_session(session_dir)
    text = str(info.value)
    assert f"points.csv row {row}" in text and repr(column) in text and repr(value) in text


def test_missing_files_and_columns(session_dir):
    (session_dir / "points.csv").write_text("point_id,sequence,kind\nA,0,static\n")
    with pytest.raises(SessionFormatError, match=r"missing column\(s\) start_s"):
        read_session(session_dir)
    (session_dir / "points.csv").unlink()
    with pytest.raises(SessionFormatError, match=r"points\.csv: missing"):
        read_session(session_dir)
    (session_dir / "session.json").unlink()
    with pytest.raises(SessionFormatError, match=r"session\.json: missing"):
        read_session(session_dir)


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"format": "piga-session/2"}, "'format' must be 'piga-session/1'"),
        ({"format": "piga-session/1", "station": {"A0_m": 0.03}}, "missing station key"),
        (
            {
                "format": "piga-session/1",
                "station": {
                    "A0_m": "0.03",
                    "latitude_deg": 39.94,
                    "g_mps2": 9.8,
                    "earth_rate_radps": 7e-5,
                    "pulses_per_rev": 16384,
                },
            },
            r"must be a finite number in \(0, 0\.1\] \(m\)",
        ),
    ],
)
def test_bad_session_json(session_dir, doc, message):
    (session_dir / "session.json").write_text(json.dumps(doc))
    with pytest.raises(SessionFormatError, match=message):
        read_session(session_dir)


def test_garbled_csv_and_short_rows(session_dir):
    path = session_dir / "points.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], lines[1].rsplit(",", 3)[0]]) + "\n")
    with pytest.raises(SessionFormatError, match="row 2: expected 11 fields"):
        read_session(session_dir)
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(SessionFormatError, match=r"points\.csv"):
        read_session(session_dir)


def test_bad_raw_arrays(session_dir, session):
    """physics.md's raw/<point_id>.npz, and the same checks for the raw.h5 the station writes."""
    (session_dir / "raw.h5").unlink()
    (session_dir / "raw").mkdir()
    pid = next(iter(session.raw))
    np.savez(
        session_dir / "raw" / f"{pid}.npz",
        grating_t=np.arange(3.0),
        grating_z=np.array([0, np.nan, 1.0]),
        pulse_t=np.arange(2.0),
    )
    with pytest.raises(SessionFormatError, match=rf"raw/{pid}.npz, column 'grating_z'.*NaN"):
        read_session(session_dir)
    np.savez(
        session_dir / "raw" / f"{pid}.npz", grating_t=np.arange(3.0), grating_z=np.arange(3.0), pulse_t=np.arange(2.0)
    )
    np.savez(
        session_dir / "raw" / "nobody.npz", grating_t=np.arange(3.0), grating_z=np.arange(3.0), pulse_t=np.arange(2.0)
    )
    with pytest.raises(SessionFormatError, match="no point with this point_id"):
        read_session(session_dir)


def test_raw_h5_is_checked_like_the_npz(session_dir, session):
    pid = next(iter(session.raw))
    with h5py.File(session_dir / "raw.h5", "r+") as f:
        del f[pid]["grating_z"]
        f[pid]["grating_z"] = np.array([0.0, np.nan, 1.0])
    with pytest.raises(SessionFormatError, match=rf"raw\.h5:/{pid}, column 'grating_z'.*NaN"):
        read_session(session_dir)
    with h5py.File(session_dir / "raw.h5", "r+") as f:
        del f[pid]["grating_z"]
        f[pid]["grating_z"] = session.raw[pid].grating_z
        f.create_group("nobody")
    with pytest.raises(SessionFormatError, match="no point with this point_id"):
        read_session(session_dir)
    (session_dir / "raw").mkdir()
    np.savez(session_dir / "raw" / f"{pid}.npz", grating_t=np.arange(3.0), grating_z=np.arange(3.0),
             pulse_t=np.arange(2.0))  # fmt: skip
    with pytest.raises(SessionFormatError, match=r"raw/\*\.npz or raw\.h5, not both"):
        read_session(session_dir)


def test_import_is_all_or_nothing(tmp_path, session_dir):
    db = tmp_path / "db.sqlite"
    set_cell(session_dir, 7, "Tm_s", "nan")  # a defect on a late row
    assert main(["import", str(session_dir), "--db", str(db)]) == 2
    with SessionStore(db) as store:
        assert store.sessions() == []  # nothing half-imported


def test_identify_command_writes_the_schema(tmp_path, session_dir):
    (session_dir / "raw.h5").unlink()
    out = tmp_path / "r.json"
    # 3 positions x 2 frequencies: too few to separate four coefficients with a static level each? 6 vib + 3 static
    assert main(["identify", str(session_dir), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["method"] == "integral"
    assert set(doc["coefficients"]) == {"kz", "kzz", "ky", "k3"}
    assert {"value", "sigma"} <= set(doc["coefficients"]["kzz"])
    # eq. 28 as the seed defines it: N = the 6 vibration test points
    assert doc["n_points"] == 9 and doc["mu_c"] == pytest.approx(1.25 + np.log(np.sqrt(6 / 3)))
    assert main(["identify", str(session_dir), "--json", str(out), "--method", "baseline"]) == 0
    base = json.loads(out.read_text())
    assert base["method"] == "baseline" and base["coefficients"]["kz"]["value"] is None
