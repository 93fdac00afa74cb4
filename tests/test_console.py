"""What the console prints: facts on stdout (units, u and U = k u; the run, the fit check and conformity on
their own lines), progress and the analysis-and-report stage on stderr; and station.coefficients, which reads
any method's results for it."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from quick_run import run_quick_session

from station.coefficients import coefficient_rows, conclusion, format_rows

UNITS = {"kz": "rad/s/g", "kzz": "rad/s/g^2", "ky": "rad/s/g^2", "k3": "rad/s/g^3"}


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> subprocess.CompletedProcess:
    return run_quick_session(tmp_path_factory.mktemp("console"))


def test_stdout_has_units_uncertainty_meaning_and_the_fit_check_and_no_progress(run):
    out = run.stdout
    assert "\r" not in out and "station-s [" not in out and "progress:" not in out  # no bar in a redirected log
    for name, unit in UNITS.items():  # every printed coefficient carries its unit, on the value and on u and U
        line = next(x for x in out.splitlines() if x.strip().startswith(f"{name} ") and "=" in x)
        assert line.count(unit) == 3, line
        assert re.search(r"U = \S+ " + re.escape(unit) + r" \(k = [\d.]+", line), line
    assert "residual sigma = " in out and " rad/s" in out
    assert "u is the standard uncertainty (k = 1" in out and "mu_c = 1.25 + ln sqrt(N/3)" in out
    run_line, fit, conformity = out.strip().splitlines()[-3:]  # the fit check apart from conformity
    assert run_line == "run: finished, no fault", run_line
    assert re.fullmatch(r"fit check: (passed|FAILED): integral: mu [\d.]+ [<>=]+ mu_c [\d.]+ .*", fit), fit
    assert conformity.startswith("conformity against the instrument's limits: not decided by the fit check; see ")
    assert "ACCEPTED" not in out and "resume with" not in out


def test_stderr_shows_progress_then_the_analysis_and_report_stage(run):
    err = run.stderr.splitlines()
    progress = [x for x in err if x.startswith("progress: ")]
    assert 3 <= len(progress) <= 11  # one line per tenth of the plan in a log, not a carriage-return bar
    measured = next(i for i, x in enumerate(err) if x.startswith("measuring finished: 20/20"))
    started = next(i for i, x in enumerate(err) if x.startswith("analysis and report: fitting"))
    done = next(i for i, x in enumerate(err) if re.match(r"analysis and report: done in [\d.]+ s", x))
    assert max(err.index(p) for p in progress) < measured < started < done


SEED000_DOC = {  # the shape of procedures.integral_precession.identify's to_json, with a GUM budget on kz only
    "method": "integral",
    "coefficients": {
        "kz": {"value": 0.56, "sigma": 2.8e-4, "unit": "rad/s/g", "standard_uncertainty": 3.0e-4,
               "coverage_factor": 2.2, "coverage_probability": 0.95, "expanded_uncertainty": 6.6e-4},
        "kzz": {"value": 6.0e-6, "sigma": 4.0e-8},
        "ky": {"value": None, "sigma": None, "note": "not identifiable by the baseline model"},
    },
    "units": {"kzz": "rad/s/g^2", "ky": "rad/s/g^2"},
    "mu": 1.4, "mu_c": 2.2, "reliable": True, "n_points": 20, "dof": 5,
}  # fmt: skip


def test_coefficient_rows_read_both_shapes_and_the_budget():
    rows = {r.name: r for r in coefficient_rows({"integral": SEED000_DOC, "alignment": {
        "dtheta_h": {"value": 1e-4, "sigma": 2e-5, "unit": "rad"}}})}  # fmt: skip
    kz, kzz, ky, dth = rows["kz"], rows["kzz"], rows["ky"], rows["dtheta_h"]
    assert (kz.u, kz.k, kz.expanded, kz.u_fit, kz.budgeted) == (3.0e-4, 2.2, 6.6e-4, 2.8e-4, True)
    assert (kzz.unit, kzz.u, kzz.budgeted) == ("rad/s/g^2", 4.0e-8, False)
    assert kzz.k == pytest.approx(2.5706, abs=1e-4)  # no budget: Student's t at the fit's 5 dof, not a fixed 2
    assert kzz.expanded == pytest.approx(kzz.k * 4.0e-8, rel=1e-15)
    assert dth.k is None and dth.expanded is None  # no dof stated: no U
    assert ky.value is None and "not identifiable" in ky.note
    assert (dth.result, dth.unit) == ("alignment", "rad")  # the results key it came from
    lines = format_rows([kz, kzz, ky])
    assert "U = 6.60e-04 rad/s/g (k = 2.20, 95 %)" in lines[0] and "fit alone 2.80e-04" in lines[0]
    assert "(k = 2.57, 95 %)" in lines[1] and "not identified" in lines[2]
    assert "U not stated" in format_rows([dth])[0]


def test_rows_of_a_seed001_tumble_have_units_once_per_block_with_their_budget():
    """seed 001's results: per-temperature blocks in a list, each coefficient stated plainly and again in its
    GUM block; the console shows each once per block, with its unit and the budget's k."""
    import numpy as np

    import procedures.tumble.procedure  # noqa: F401 - registers the procedure
    from procedures.tumble.tumble_session import tumble_session
    from station.engine.registry import get_procedure
    from station.twin.pendulous_accelerometer import AccelerometerModel

    temperatures = [20, 80, -40, 20]
    session, _ = tumble_session(AccelerometerModel(), temperatures, 3, 1e-5, np.random.default_rng(1))
    results = get_procedure("tumble").analyse(session).results
    rows = coefficient_rows(results)
    k1 = [r for r in rows if r.name == "K1"]
    budget_k = [t["coefficients"]["K1"]["coverage_factor"] for t in results["eight_point"]["temperatures"]]
    assert len(k1) == len(temperatures) and all(r.unit == "V/g" and r.budgeted for r in k1)
    assert [r.k for r in k1] == budget_k  # the budget's own k (Student's t at its nu_eff), not a fixed 2
    assert all(r.unit for r in rows), [r.name for r in rows if not r.unit]
    assert {r.unit for r in rows if r.name.startswith("drift")} == {"g/s"}


def test_the_console_separates_the_fit_check_from_conformity_and_accepts_nothing_untested():
    lines = conclusion("finished", {"integral": SEED000_DOC}, certificate=True)
    assert lines == ["run: finished, no fault",
                     "fit check: passed: integral: mu 1.40 < mu_c 2.20 (no outlier), 20 points",
                     "conformity against the instrument's limits: not decided by the fit check; see the "
                     "certificate beside the report"]  # fmt: skip
    untested = conclusion("finished", {"tumble": {"K1": {"value": 1.0, "sigma": 0.1}}})
    assert untested[1].startswith("fit check: none (this method reports no outlier test")
    assert not any("ACCEPTED" in x or "passed" in x for x in untested)
    aborted = conclusion("aborted", None, ["DeviceTimeout: counter: no answer"])
    assert aborted[:2] == ["run: aborted; 1 fault: DeviceTimeout: counter: no answer",
                           "fit check: none (no analysis for this run)"]  # fmt: skip


def test_the_pause_prompt_goes_to_stderr(monkeypatch, capsys):
    import io

    from station.cli.signals import RunSignals

    monkeypatch.setattr("sys.stdin", io.StringIO("r\n"))
    signals = RunSignals(None)  # type: ignore[arg-type]  # the prompt needs no controller
    assert signals.ask("paused at a safe point: [r]esume or [a]bort? ").strip() == "r"
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    with pytest.raises(EOFError):
        signals.ask("again? ")
    captured = capsys.readouterr()
    assert captured.out == "" and "paused at a safe point: [r]esume or [a]bort? " in captured.err


def test_an_aborted_run_prints_its_resume_command(tmp_path):
    import signal
    import time

    from quick_run import QUICK_TOML, REPO

    (tmp_path / "quick.toml").write_text(QUICK_TOML)
    db = tmp_path / "station.sqlite"
    cmd = [sys.executable, "-m", "station.cli.cli", "run", str(tmp_path / "quick.toml"), "--out", str(tmp_path),
           "--speed", "20"]  # fmt: skip
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        t0 = time.monotonic()
        while not _has_points(db):
            assert child.poll() is None and time.monotonic() - t0 < 120, child.communicate()
            time.sleep(0.1)
        child.send_signal(signal.SIGTERM)
        out, err = child.communicate(timeout=120)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 1, out + err
    uid = re.search(r"^session (\S+):", out, re.M).group(1)
    assert f"resume with: station resume {uid} --out {tmp_path} --speed 20.0" in out.splitlines(), out


def _has_points(db) -> bool:
    import sqlite3

    if not db.exists():
        return False
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as con:
            return con.execute("SELECT COUNT(*) FROM points").fetchone()[0] >= 1
    except sqlite3.OperationalError:  # the child has not made its tables yet
        return False


def test_simulate_writes_no_carriage_return_into_a_log(tmp_path):
    from quick_run import REPO

    r = subprocess.run([sys.executable, "-m", "station.cli.cli", "simulate", str(tmp_path / "s")], capture_output=True,
                       cwd=REPO, timeout=240)  # fmt: skip  # bytes: text mode would turn "\r" into "\n"
    assert r.returncode == 0, r.stderr
    assert b"\r" not in r.stderr and b"simulate: 40/40 points" in r.stderr, r.stderr


def test_a_partial_twin_file_keeps_the_default_noise(tmp_path):
    from station.cli.cli import _load_twin
    from station.twin.config import default_twin

    path = tmp_path / "twin.toml"
    path.write_text("[effects.waveform_fundamental]\nz0 = -1.299e-4\nz1 = 3.2e-6\n")
    twin, default = _load_twin(str(path)), default_twin()
    assert twin.noise == default.noise and twin.noise.rate_noise_radps > 0  # not a noise-free session
    assert (twin.station, twin.instrument, twin.earth_rate_on) == (default.station, default.instrument, True)
    assert dict(twin.effects["waveform_fundamental"])["z1"] == 3.2e-6
    path.write_text("[noise]\ntiming_jitter_s = 2e-7\n[instrument]\nkz = 0.5\n")  # a key keeps its section's rest
    twin = _load_twin(str(path))
    assert twin.noise.timing_jitter_s == 2e-7 and twin.noise.rate_noise_radps == default.noise.rate_noise_radps
    assert twin.instrument.kz == 0.5 and twin.instrument.kzz == default.instrument.kzz
