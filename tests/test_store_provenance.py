"""Provenance: every session says which software, station, operator and host made it, when, simulated or not, with
which seed and instrument; a real station refuses to start without the instrument's serial number."""

import getpass
import json
import re
import socket
from pathlib import Path

import pytest

from station.cli.cli import main
from station.htmlkit import with_provenance
from station.interchange import read_session, write_session
from station.provenance import PROVENANCE_KEYS, ProvenanceError, make_provenance, software_version
from station.session import Session, StationInfo
from station.store import SessionStore

CONFIG = Path(__file__).resolve().parents[1] / "config"


def test_software_version_names_the_package_and_the_commit():
    # this source tree is a git checkout: the version carries its commit
    assert re.fullmatch(r"\d+\.\d+\.\d+(\+g[0-9a-f]{12}(\.dirty)?)?", software_version())
    assert "+g" in software_version()


def test_a_simulated_session_records_where_it_came_from(tmp_path):
    prov = make_provenance(station_id="station-sim", simulated=True, seed=7)
    assert tuple(prov) == PROVENANCE_KEYS
    assert prov["operator"] == getpass.getuser() and prov["host"] == socket.gethostname()
    assert prov["simulated"] is True and prov["seed"] == 7 and prov["instrument_serial"] == "SIM-PIGA-0001"
    with SessionStore(tmp_path / "db.sqlite") as store:
        uid = store.create_session(StationInfo(), "test", instrument_serial="X", provenance=prov)
        assert store.provenance(uid) == prov
        d = write_session(store.load_session(uid), tmp_path / "out")
    assert json.loads((d / "session.json").read_text())["provenance"] == prov
    assert read_session(d).provenance == prov


def test_a_real_station_needs_the_instrument_serial():
    with pytest.raises(ProvenanceError, match=r"'lab-1' is a real station: the instrument serial number is required"):
        make_provenance(station_id="lab-1", simulated=False, instrument_serial="  ")
    prov = make_provenance(station_id="lab-1", simulated=False, instrument_serial="PIGA-0042", seed=3, operator="ann")
    assert (prov["instrument_serial"], prov["seed"], prov["operator"]) == ("PIGA-0042", None, "ann")


def test_the_console_refuses_a_real_station_without_a_serial_before_opening_anything(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["run", str(CONFIG / "procedures" / "integral_precession.toml"), "--station", str(CONFIG / "stations" /
    "vibration.toml"),
                 "--out", str(out)])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "lab-vibration-table-1" in err and "instrument serial number is required" in err and "--serial" in err
    assert not (out / "station.sqlite").exists()  # refused before the store or any device was opened


def test_every_report_carries_the_provenance():
    prov = make_provenance(station_id="station-sim", simulated=True, seed=1)
    html = with_provenance("<html><body><h1>Report</h1><p>fit</p></body></html>", prov)
    assert html.index("Provenance") > html.index("</h1>") and "station-sim" in html and "SIM-PIGA-0001" in html
    assert "not recorded" in with_provenance("<h1>R</h1>", {"station_id": None})


def test_a_session_without_provenance_exports_without_inventing_one(tmp_path):
    s = Session(StationInfo(), [], meta={}, measurements=[])
    d = write_session(s, tmp_path / "bare")
    assert "provenance" not in json.loads((d / "session.json").read_text())


def _control_rig(tmp_path, seed: int):
    """A simulated station under a controller and its control channel (closed by the caller's ExitStack)."""
    from drivers.config import load_station_config
    from drivers.station import simulated_station
    from station.cli.control import ControlServer
    from station.cli.controller import StationController
    from station.control_channel import ControlClient
    from station.twin.config import default_twin

    config = load_station_config(CONFIG / "stations/vibration-sim.toml")
    sim = simulated_station(config, default_twin(), seed=seed)
    db = SessionStore(tmp_path / "s.db")
    controller = StationController(sim.devices, db, config.station_model(), reports_dir=tmp_path)
    server = ControlServer(controller, "tcp://127.0.0.1:*", token="t" * 32).start()
    client = ControlClient(server.endpoint, token="t" * 32, timeout_s=20)
    return sim, db, controller, server, client


QUICK = {"positions_deg": [0, 60, 180, 240], "freqs_hz": [10], "window_s": 5, "settle_s": 0}  # the fewest that identify


def test_a_real_station_refuses_a_start_from_the_panel_without_a_serial(tmp_path):
    import dataclasses

    sim, db, controller, server, client = _control_rig(tmp_path, seed=1)
    try:
        sim.devices.config = dataclasses.replace(sim.devices.config, simulated=False, station_id="lab-2")
        reply = client.request("start", {"procedure": "integral_precession", "params": QUICK}, user="bob")
        assert not reply["ok"] and reply["error"]["type"] == "ProvenanceError"
        assert "'lab-2' is a real station" in reply["error"]["message"]
        assert db.sessions() == [] and not controller.busy  # nothing started, nothing stored
    finally:
        server.close()
        sim.close()
        db.close()


def test_the_panels_user_is_the_operator_of_the_session_it_starts(tmp_path):
    """A run started over the control channel on behalf of a logged-in user records that user; the station file's
    id, the simulated station's seed and the serial given go with it."""
    sim, db, controller, server, client = _control_rig(tmp_path, seed=23)
    try:
        args = {"procedure": "integral_precession", "params": QUICK, "instrument_serial": "PIGA-7"}
        uid = client.request("start", args, user="alice")["result"]["session_uid"]
        controller.wait(120)
        prov = db.provenance(uid)
    finally:
        server.close()
        sim.close()
        db.close()
    assert (prov["operator"], prov["station_id"], prov["seed"], prov["simulated"]) == ("alice", "station-sim", 23, True)
    assert prov["instrument_serial"] == "PIGA-7"


def test_the_procedure_files_instrument_serial_is_recorded(tmp_path):
    """`instrument_serial` in a procedure file names the instrument of the session (no silent default)."""
    proc = tmp_path / "quick.toml"
    proc.write_text('procedure = "integral_precession"\ninstrument_serial = "PIGA-FILE-9"\n[params]\n'
                    'positions_deg = [0, 120, 240]\nfreqs_hz = [9, 10]\nwindow_s = 5\nsettle_s = 0\n')  # fmt: skip
    out = tmp_path / "out"
    main(["run", str(proc), "--out", str(out), "--seed", "4"])  # the analysis may refuse so short a session
    with SessionStore(out / "station.sqlite") as store:
        (row,) = store.sessions()
        prov = store.provenance(row["uid"])
    assert row["instrument_serial"] == prov["instrument_serial"] == "PIGA-FILE-9" and prov["seed"] == 4
    main(["run", str(proc), "--out", str(out), "--serial", "PIGA-CLI-1", "--dry-run"])  # the command line wins
