"""Bad input gets a clear error naming what is wrong, or a clear "cannot tell with this design"."""

from __future__ import annotations

import csv
from dataclasses import replace

import pytest

from station.cli.cli import main
from station.gap.api import diagnose
from station.gap.design import GapInputError
from station.interchange import write_session
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session


def _session(twin, positions, freqs, seed=1):
    return simulate_session(multiposition_plan(positions, freqs, window_s=100.0), twin, seed)


def test_a_session_from_another_station_geometry_is_refused(twin, tmp_path, capsys):
    other = replace(twin, station=replace(twin.station, A0_m=0.025))
    session = _session(other, [0.0, 45.0, 135.0, 180.0, 225.0, 315.0], (8.0, 10.0))
    with pytest.raises(GapInputError, match=r"another station geometry: A0_m = 0.025 in the session but 0.03"):
        diagnose(session, twin)
    write_session(session, tmp_path / "s")
    assert main(["gap", str(tmp_path / "s"), "--json", str(tmp_path / "g.json")]) == 2
    assert "A0_m" in capsys.readouterr().err
    assert not (tmp_path / "g.json").exists()


def test_too_few_points_to_fit_is_refused(twin):
    session = _session(twin, [0.0, 180.0], (10.0,))
    with pytest.raises(GapInputError, match=r"too few points to fit: 4 points cannot fit the bias k0 and 4 calibrated"):
        diagnose(session, twin)


def test_a_session_without_vibration_is_refused(twin):
    session = _session(twin, [0.0, 45.0, 135.0, 180.0, 225.0, 315.0], ())
    with pytest.raises(GapInputError, match="no vibration points"):
        diagnose(session, twin)


def test_a_design_that_cannot_fit_the_calibrated_coefficients_is_refused(twin):
    """One position: ky (sin^2 theta) is never excited."""
    session = _session(twin, [0.0], (6.0, 7.0, 8.0, 9.0, 10.0))
    with pytest.raises(GapInputError, match="cannot fit the calibrated coefficients: no point excites ky"):
        diagnose(session, twin)


def test_too_few_residual_dof_gives_unexplained_with_the_reason(twin):
    """6 points, the bias k0 + 4 coefficients: 1 dof, below the 4 the tests need: nothing can be tested, and a
    `cannot_tell` would name no effect (issue 28), so `unexplained` saying why."""
    rep = diagnose(_session(twin, [0.0, 45.0], (8.0, 10.0)), twin)
    assert rep.verdict.verdict == "unexplained"
    assert "not testable with this design: only 1 residual degrees of freedom" in rep.verdict.text
    assert rep.verdict.remaining and "add positions or frequencies" in rep.verdict.remaining[0]
    assert rep.effects == [] and all(c["rank"] is None for c in rep.candidates)


def test_a_vibration_point_without_timing_capture_is_refused(twin):
    session = _session(twin, [0.0, 45.0, 135.0, 180.0, 225.0, 315.0], (8.0, 10.0))
    session.points[0] = replace(session.points[0], t1_s=None)
    with pytest.raises(GapInputError, match=rf"without timing capture \(t1, t2, Np\): {session.points[0].point_id}"):
        diagnose(session, twin)


def test_a_format_error_names_file_row_and_column(twin, tmp_path, capsys):
    path = write_session(_session(twin, [0.0, 45.0, 135.0, 180.0, 225.0, 315.0], (8.0, 10.0)), tmp_path / "s")
    rows = list(csv.DictReader((path / "points.csv").open()))
    rows[3]["Tm_s"] = "fast"  # the 4th point: line 5 of the file, after the header
    with (path / "points.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    assert main(["gap", str(path), "--json", str(tmp_path / "g.json")]) == 2
    err = capsys.readouterr().err
    assert "points.csv row 5" in err and "'Tm_s'" in err and "'fast'" in err


def test_a_missing_store_is_named_and_not_created(tmp_path, capsys):
    store = tmp_path / "none.sqlite"
    assert main(["gap", "--db", str(store), "S1", "--json", str(tmp_path / "g.json")]) == 2
    assert f"no store {store}" in capsys.readouterr().err
    assert not store.exists()


def test_an_unknown_effect_to_leave_out_is_named(twin, tmp_path, capsys):
    path = write_session(_session(twin, [0.0, 45.0, 135.0, 180.0, 225.0, 315.0], (8.0, 10.0)), tmp_path / "s")
    assert main(["gap", str(path), "--json", str(tmp_path / "g.json"), "--exclude", "wobble"]) == 2
    assert "unknown candidate effect(s) ['wobble']" in capsys.readouterr().err
