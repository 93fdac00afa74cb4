"""The notebook API (`station.open_store`) on a store a real engine run wrote, and the example notebook run by nbclient.

The store comes from `station run` of a quick seed-000 session (20 points, 30 s windows) on the simulated
station; the DataFrames are checked against what the run itself wrote (its result JSON, the store's rows)
and the rates against eq. 17 computed here from pulses and Tm.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient
from quick_run import REPO, run_quick_session

from station.coefficients import student_k
from station.errors import InputError
from station.store import SessionStore

NOTEBOOK = REPO / "examples" / "session_in_a_notebook.ipynb"
CELL_TIMEOUT_S = 120


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("nb")
    run_quick_session(out)
    return out


def test_import_station_stays_light():
    """`import station` loads no pandas; `station.open_store` (a lazy attribute) does, on first use."""
    code = (
        "import sys, station; light = 'pandas' not in sys.modules; station.open_store; "
        "print(light, 'pandas' in sys.modules)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert r.stdout.split() == ["True", "True"], r.stderr


def test_open_store_refuses_a_missing_store(tmp_path):
    with pytest.raises(InputError, match="no session store there"):
        import station

        station.open_store(tmp_path / "nope.sqlite")


def test_sessions_as_dataframes_match_the_store_and_the_run(run_dir):
    import station

    db = run_dir / "station.sqlite"
    with station.open_store(db) as store:
        assert len(store) == 1 and list(store.sessions["status"]) == ["finished"]
        s = store.session()
        with pytest.raises(InputError, match="not in"):
            store.session("no-such-uid")
        points = s.points
        assert len(points) == 20 and set(points["kind"]) == {"vibration", "static"}
        # eq. 17 from the recorded columns, independently of Session.rates_radps
        with SessionStore(db) as raw:
            ppr = raw.load_session(s.uid).station.pulses_per_rev
        expected = 2 * math.pi * points["pulses"] / (ppr * points["Tm_s"])
        assert (points["rate_radps"] - expected).abs().max() <= 1e-12 * expected.abs().max()
        assert points["freq_hz"].dtype.kind == "f" and points["start_s"].is_monotonic_increasing
        assert {"finished"} <= set(s.events["message"])
        results = s.results
        written = json.loads((run_dir / f"result-{s.uid}.json").read_text())
        for method in ("integral", "baseline"):
            for name, c in written[method]["coefficients"].items():
                row = results[(results.result == method) & (results.coefficient == name)].iloc[0]
                if c["value"] is None:
                    assert math.isnan(row.value) and "not identifiable" in row.note
                    continue
                # u and U are the GUM budget's where the method states one, else the fit's sigma and t at its dof
                u = c.get("standard_uncertainty", c["sigma"])
                big_u = c.get("expanded_uncertainty", student_k(written[method]["dof"]) * c["sigma"])
                assert row.value == c["value"] and row.u == u and row.u_fit == c["sigma"]
                assert pytest.approx(big_u, rel=1e-15) == row.U and pytest.approx(big_u / u, rel=1e-12) == row.k
                assert row.unit == written[method]["units"][name]


def test_a_result_displays_its_units_uncertainty_meaning_and_fit_check(run_dir):
    import station

    with station.open_store(run_dir / "station.sqlite") as store:
        s = store.session()
        r = s.result("integral")
        html = r._repr_html_()
        for text in ("rad/s/g^2", "rad/s/g^3", "u (k = 1)", "U = k u", "mu_c", "standard uncertainty"):
            assert text in html, text
        doc = s.result_docs()["integral"]
        passed = doc["mu"] < doc["mu_c"]
        assert r.conclusion[1].startswith(f"fit check: {'passed' if passed else 'FAILED'}: integral: mu ")
        assert not any("ACCEPTED" in line for line in r.conclusion) and "fit check" in html
        assert "integral" in s._repr_html_() and s.uid in store._repr_html_()
        with pytest.raises(InputError, match="no result 'nope'"):
            s.result("nope")
    # A fit with an outlier (mu >= mu_c, seed 000 eq. 28) fails the fit check, and says why; conformity is the
    # certificate's, never the fit check's.
    bad = station.notebook.Result("integral", {**doc, "mu": doc["mu_c"] + 0.5, "reliable": False})
    assert bad.conclusion[1].startswith("fit check: FAILED") and "outlier" in bad.conclusion[1]
    assert bad.conclusion[2].startswith("conformity against the instrument's limits: not decided")


def test_the_example_notebook_runs_on_a_simulated_session(run_dir):
    nb = nbformat.read(NOTEBOOK, as_version=4)
    env_before = os.environ.get("STATION_STORE")
    os.environ["STATION_STORE"] = str(run_dir / "station.sqlite")  # the kernel inherits the environment
    try:
        NotebookClient(nb, timeout=CELL_TIMEOUT_S, kernel_name="python3",
                       resources={"metadata": {"path": str(run_dir)}}).execute()  # fmt: skip
    finally:
        if env_before is None:
            os.environ.pop("STATION_STORE", None)
        else:
            os.environ["STATION_STORE"] = env_before
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    html = "\n".join(o.get("data", {}).get("text/html", "") for o in outputs)
    text = "\n".join(o.get("text", "") for o in outputs)
    written = json.loads(next(run_dir.glob("result-*.json")).read_text())
    kz = written["integral"]["coefficients"]["kz"]
    assert f"kz = {kz['value']:.6e} rad/s/g" in text
    assert "U = k u" in html and "fit check: " in html and "conformity against the instrument" in html
    assert "Verdict:" in html  # the gap report's rich display


def test_session_takes_the_latest_finished_one_and_says_which(tmp_path, capsys):
    import station
    from station.twin.config import TwinConfig
    from station.twin.plan import multiposition_plan
    from station.twin.session_sim import simulate_session

    info = simulate_session(multiposition_plan([0.0], [10.0], window_s=20.0), TwinConfig(), seed=1).station
    db = tmp_path / "db.sqlite"
    with SessionStore(db) as raw:
        done = raw.create_session(info, "integral_precession", status="finished")
        raw.create_session(info, "integral_precession", status="failed")  # the latest: a failed run
    with station.open_store(db) as store:
        assert store.session().uid == done
        said = capsys.readouterr().out
        assert said.startswith(f"session {done}: the latest finished of 2 in the store (") and "finished" in said
        (failed,) = [u for u in store.sessions["uid"] if u != done]
        assert store.session(status=None).uid == failed and store.session(failed).uid == failed
        with pytest.raises(InputError, match="no aborted session"):
            store.session(status="aborted")
