"""Procedures renamed after their packages (issue 29): sessions stored and procedure files written under the
former names (seed000.integral_precession, ...) still load, resume, analyse and run."""

from __future__ import annotations

import sqlite3
import time

import pytest

from station.cli import analysis_job
from station.engine.registry import get_procedure, load_library, load_procedure_file
from station.engine.runner import State
from station.procedure_names import FORMER_NAMES

from .conftest import PROCEDURE, QUICK

pytestmark = pytest.mark.timeout(120)
FORMER = "seed000.integral_precession"


def test_every_former_name_resolves_to_the_procedure_of_its_package() -> None:
    library = load_library()
    assert get_procedure(FORMER) is get_procedure("integral_precession")
    assert set(FORMER_NAMES.values()) == set(library)  # every procedure had a former name, none is lost
    assert not set(FORMER_NAMES) & set(library)


def test_a_procedure_file_naming_a_former_name_still_runs(tmp_path) -> None:
    path = tmp_path / "old.toml"
    path.write_text('procedure = "seed003.planning"\n[params]\n')
    spec, _ = load_procedure_file(path)
    assert spec.name == "multiposition.planning"


def test_a_session_stored_under_a_former_name_resumes_and_is_analysed_again(make_rig, tmp_path) -> None:
    rig = make_rig(speed=300.0)
    uid, _ = rig.controller.start(PROCEDURE, QUICK)
    t0 = time.monotonic()
    while rig.controller.status()["done"] < 4:
        assert time.monotonic() - t0 < 60, "no points were stored"
        time.sleep(0.01)
    rig.controller.abort()
    rig.controller.wait(30)
    with sqlite3.connect(rig.store.path) as con:  # as an earlier version stored it
        con.execute("UPDATE sessions SET procedure = ?, config_json = json_set(config_json, '$.procedure', ?) "
                    "WHERE uid = ?", (FORMER, FORMER, uid))  # fmt: skip
    assert rig.store.session_config(uid)["procedure"] == FORMER

    rig.controller.resume_session(uid)
    out = rig.controller.wait(60)
    assert out.state == State.FINISHED and out.session_uid == uid
    assert [p.sequence for p in rig.store.load_session(uid).points] == list(range(10))
    assert out.analysis is not None and set(out.analysis.results) == {"integral", "baseline"}

    report = tmp_path / "again.html"
    assert analysis_job.main([FORMER, str(rig.store.path), uid, str(report)]) == 0
    assert report.read_text().startswith("<!doctype html>")
