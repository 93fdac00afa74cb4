"""GUM fields on the console and in `station identify --json` (issue 32, deliverables 3 and 4): k is Student's t
at each quantity's degrees of freedom, never a fixed 2."""

import json
import math

import numpy as np
import pytest
import scipy.stats

from procedures.integral_precession.procedure import analyse_alignment
from station.cli.cli import main
from station.coefficients import coefficient_rows, format_rows
from station.interchange import write_session
from station.session import PointRecord, Session
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session

POSITIONS_DEG = [0.0, 60.0, 120.0, 180.0, 240.0, 300.0]


@pytest.fixture(scope="module")
def session() -> Session:
    return simulate_session(multiposition_plan(POSITIONS_DEG, [8.0, 10.0], window_s=20.0), TwinConfig(), seed=3)


def test_identify_json_has_u_nu_k_u_covariance_and_budget(tmp_path, session):
    out = tmp_path / "identified.json"
    assert main(["identify", str(write_session(session, tmp_path / "s")), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["references"]["file"].endswith("references.toml")
    for name in ("kz", "kzz", "ky", "k3"):
        c = doc["coefficients"][name]
        nu = math.inf if c["effective_dof"] is None else c["effective_dof"]
        # Student's t at nu_eff, times q_95 / z_95 <= 1 where rectangular inputs flatten the output's tails
        assert 0.8 < c["shape_factor"] <= 1.0
        assert c["coverage_factor"] == pytest.approx(scipy.stats.t.ppf(0.975, nu) * c["shape_factor"], rel=1e-9)
        assert c["expanded_uncertainty"] == pytest.approx(c["coverage_factor"] * c["standard_uncertainty"], rel=1e-12)
        assert c["coverage_probability"] == 0.95 and c["standard_uncertainty"] >= c["sigma"] > 0
    cov = np.array(doc["covariance"]["matrix"])
    assert doc["covariance"]["names"] == ["kz", "kzz", "ky", "k3"]
    assert np.allclose(cov, cov.T, rtol=0, atol=1e-12 * np.abs(cov).max())
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    u = np.array([doc["coefficients"][n]["standard_uncertainty"] for n in doc["covariance"]["names"]])
    assert np.sqrt(np.diag(cov)) == pytest.approx(u, rel=1e-12)  # the same budget gave both
    sources = {r["source"] for r in doc["budget"]}
    assert {"least-squares fit (Type A, seed 000 eqs. 21-22)", "crank radius A0"} <= sources


def test_a_six_position_self_alignment_has_k_from_t_at_3_dof(session):
    static = Session(session.station, [p for p in session.points if p.kind == "static"], meta={"params": {}})
    assert len(static.points) == 6 and all(isinstance(p, PointRecord) for p in static.points)
    analysis = analyse_alignment(static)
    angle = analysis.results["alignment"]["dtheta_h"]
    assert angle["effective_dof"] == 3 and angle["coverage_factor"] == pytest.approx(3.182, abs=5e-4)
    row = next(r for r in coefficient_rows(analysis.results) if r.name == "dtheta_h")
    assert "(k = 3.18, 95 %)" in format_rows([row])[0] and "k = 3.18 at 3 dof" in analysis.summary


def test_the_example_notebook_states_no_fixed_k():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "examples" / "session_in_a_notebook.ipynb").read_text()
    assert "k = 2" not in text and "U = 2u" not in text and "Student's t" in text
