"""`station sync` from the command line, and `station serve --sync-to`'s push after each run."""

from __future__ import annotations

import contextlib
import sqlite3
from pathlib import Path
from types import SimpleNamespace

import sqlalchemy as sa

from drivers.config import load_station_config
from drivers.station import simulated_station
from station.central.cli import SyncAfterRun
from station.central.reader import CentralStore
from station.cli.cli import build_parser, main
from station.cli.controller import StationController
from station.store import SessionStore
from station.twin.config import default_twin

CONFIG = load_station_config(Path(__file__).parents[2] / "config" / "stations/vibration-sim.toml")
QUICK = {"positions_deg": [0, 72, 144, 216, 288], "freqs_hz": [10], "window_s": 30, "settle_s": 2}


def test_station_sync_pushes_then_adds_nothing_and_refuses_a_conflict(tmp_path, central_url, arrays_dir, fill,
                                                                      copy, capsys):  # fmt: skip
    db = tmp_path / "station.sqlite"
    with SessionStore(db) as store:
        uids = fill(store, ("finished", "aborted", "running"))
    sync = ["sync", str(db), "--to", central_url, "--arrays", str(arrays_dir), "--name", "lab-1"]
    assert main(sync) == 0
    out = capsys.readouterr().out
    assert f"{uids[0]}: added" in out and f"{uids[1]}: added" in out and "2 added" in out and "1 still running" in out
    assert main(sync) == 0
    assert "0 added, 0 extended, 2 unchanged" in capsys.readouterr().out
    with CentralStore(central_url, arrays_dir) as central:
        assert [r["station"] for r in central.sessions()] == ["lab-1", "lab-1"]
    restored = tmp_path / "restored.sqlite"
    copy(db, restored)
    with sqlite3.connect(restored) as conn:
        conn.execute("UPDATE results SET result_json = '{\"kz\": 5}'")
    assert main(["sync", str(restored), *sync[2:]]) == 1
    err = capsys.readouterr().err
    assert f"refused: session {uids[0]}" in err and "results '0' (#0) differs" in err


def test_station_sync_errors_name_what_is_wrong(tmp_path, arrays_dir, capsys):
    assert main(["sync", str(tmp_path / "none.sqlite"), "--to", "postgresql://x@/y", "--arrays", str(arrays_dir)]) == 2
    assert "none.sqlite: no session store there" in capsys.readouterr().err
    with SessionStore(tmp_path / "s.sqlite"):
        pass
    assert main(["sync", str(tmp_path / "s.sqlite"), "--to", "mysql://db/x", "--arrays", str(arrays_dir)]) == 2
    assert "'mysql://db/x': expected a postgresql://" in capsys.readouterr().err
    nowhere = f"postgresql://x@/y?host={tmp_path / 'no-server'}"
    assert main(["sync", str(tmp_path / "s.sqlite"), "--to", nowhere, "--arrays", str(arrays_dir)]) == 2
    assert "no-server" in capsys.readouterr().err  # libpq names the socket it could not reach


def test_serve_takes_sync_options():
    args = build_parser().parse_args(["serve", "--sync-to", "postgresql://db/h", "--sync-arrays", "/lab/arrays"])
    assert (args.sync_to, args.sync_arrays) == ("postgresql://db/h", "/lab/arrays")
    assert build_parser().parse_args(["serve"]).sync_to is None  # no central history unless configured


def test_a_station_under_control_pushes_each_session_once_it_ended(tmp_path, central_url, arrays_dir):
    with contextlib.ExitStack() as stack:  # closed in reverse: sync, controller (aborts a run), store, station
        sim = simulated_station(CONFIG, default_twin(), seed=1)
        stack.callback(sim.close)
        store = stack.enter_context(SessionStore(tmp_path / "station.sqlite"))
        controller = StationController(sim.devices, store, CONFIG.station_model(), reports_dir=tmp_path)
        stack.callback(controller.close)
        hook = SyncAfterRun(store, central_url, arrays_dir, "sim-1")
        stack.callback(hook.close)
        controller.after_run.append(hook)
        outcome = controller.run("integral_precession", QUICK)
        assert outcome.state.name == "FINISHED", outcome.faults
        assert hook.last is not None and hook.last.added == [outcome.session_uid]
        with CentralStore(central_url, arrays_dir) as central:
            row = central.row(outcome.session_uid)
            named = (getattr(store.load_session(outcome.session_uid), "provenance", None) or {}).get("station_id")
            assert row["status"] == "finished" and row["station"] == (named or "sim-1") and row["n_points"] == 10
            assert central.results(outcome.session_uid) == store.results(outcome.session_uid) != []
    engine = sa.create_engine(central_url)
    with engine.connect() as conn:
        assert conn.execute(sa.text("SELECT count(*) FROM points")).scalar() == 10
    engine.dispose()


def test_a_sync_after_run_that_cannot_reach_the_database_lets_the_station_carry_on(tmp_path, central_url, arrays_dir,
                                                                                   fill, capsys):  # fmt: skip
    with SessionStore(tmp_path / "station.sqlite") as store:
        first, second = fill(store, ("finished", "aborted"))
        down = SyncAfterRun(store, f"postgresql://x@/y?host={tmp_path / 'no-server'}", arrays_dir, "sim")
        down(SimpleNamespace(session_uid=first))  # logged, not raised: the engine thread goes on
        assert down.last is None and f"sync of {first} failed" in capsys.readouterr().err
        down.close()
        up = SyncAfterRun(store, central_url, arrays_dir, "sim")
        up(SimpleNamespace(session_uid=second))  # this session, and the one the first sync could not push
        assert sorted(up.last.added) == sorted([first, second])
        up.close()
