"""The README's main job end to end: a full simulated seed-000 session, stored, identified, reported."""

import json
import math
import re

import pytest

from app.cli import main
from station.store import SessionStore


def test_calibrate_runs_stores_identifies_and_reports(tmp_path, capsys):
    assert main(["calibrate", "--out", str(tmp_path), "--seed", "11"]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"^\s+kzz\s+= ", printed, re.M) and "u = " in printed and "U = " in printed  # value, u, U = k u
    with SessionStore(tmp_path / "station.sqlite") as store:
        (session,) = store.sessions()
        assert session["n_points"] == 40 and session["status"] == "finished"
        results = {r["method"]: r["result"] for r in store.results(session["uid"])}
    integral = results["integral"]["coefficients"]
    truth = {"kz": 0.56, "kzz": 6e-6, "ky": 5e-6, "k3": 7e-7}
    for name, value in truth.items():
        c = integral[name]
        assert abs(c["value"] - value) < 5 * c["sigma"], name  # a 5-sigma miss is a defect, not bad luck
    # The reliability test of eq. 28 is reported, consistently (a random outlier may fail it: that is its job).
    integral_result = results["integral"]
    # eq. 28 as the seed defines it: N = the 30 test points (rows of Y); the joint variant counts all 40 rates
    assert integral_result["mu_c"] == pytest.approx(1.25 + math.log(math.sqrt(30 / 3)))
    assert integral_result["mu_c_joint"] == pytest.approx(1.25 + math.log(math.sqrt(40 / 3)))
    assert integral_result["reliable"] == (integral_result["mu"] < integral_result["mu_c"])
    # the certificate is written beside the report (issue 15)
    assert next(tmp_path.glob("certificate-*.pdf")).read_bytes().startswith(b"%PDF")
    assert "SIMULATED" in next(tmp_path.glob("certificate-*.html")).read_text()
    report = next(tmp_path.glob("report-*.html")).read_text()
    assert "<svg" in report and "Timing capture" in report and "http" not in report.split("<svg")[0]
    result = json.loads(next(tmp_path.glob("result-*.json")).read_text())
    assert result["baseline"]["coefficients"]["kz"]["value"] is None
    assert (next(tmp_path.glob("session-*")) / "points.csv").is_file()
