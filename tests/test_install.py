"""A plain install works: `pip install .` (not editable) into a fresh venv puts four import names in site-packages
(station, drivers, procedures, web) and nothing else of ours; from an empty folder shipped files are taken by name
and `station calibrate` runs the main job with the defaults shipped as data of the station package (station/_config)
and the panel's uPlot inside the package. That
run is also the README's main job checked end to end (a full simulated seed-000 session, stored, identified,
reported, certified): one run of the 6.5 h session serves both.

The fresh venv takes the third-party dependencies from the development venv (a .pth line; nothing is
downloaded, so the test runs offline), and the package itself is built from a copy of the source tree and installed
without them (`--no-deps --no-index`). That the dependencies are declared is checked separately, from the
imports of the code (test_every_imported_package_is_declared)."""

import ast
import importlib.metadata
import json
import math
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest

from station.extras import EXTRA_OF_MODULE
from station.store import SessionStore

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("station", "drivers", "procedures", "web")


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _requirement_names(reqs: list[str]) -> set[str]:
    return {re.split(r"[\s\[<>=!~;]", r, maxsplit=1)[0].lower().replace("_", "-") for r in reqs}


EXTRA_PARTS = {  # extra of pyproject.toml -> the part of the tree that may import its packages
    "fleet": ("station/central/", "station/fanout.py"),
    "notebook": ("station/notebook.py",),
    "web": ("web/", "station/cli/panel.py"),
}


def test_every_imported_package_is_declared():
    """Every third-party module the code imports belongs to a declared distribution: a main dependency anywhere,
    an extra's only in that extra's part of the tree (EXTRA_PARTS), so a plain install never reaches it on the
    main path; and station.extras names the extra of each (what a command without it says to install)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    main_deps = _requirement_names(project["dependencies"])
    extras = {k: _requirement_names(v) for k, v in project["optional-dependencies"].items()}
    dists = importlib.metadata.packages_distributions()
    stdlib = set(sys.stdlib_module_names) | {"__future__"}
    missing = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if "node_modules" in path.parts:
                continue
            rel = path.relative_to(ROOT).as_posix()
            allowed = main_deps.union(*(extras[e] for e, parts in EXTRA_PARTS.items() if rel.startswith(parts)))
            for name in sorted(_imports(path) - stdlib - set(PACKAGES)):
                owners = {d.lower().replace("_", "-") for d in dists.get(name, [])}
                extra = EXTRA_OF_MODULE.get(name)  # the one declaration the commands' refusals name
                if not owners & allowed & (main_deps if extra is None else extras[extra]):
                    missing.append(f"{rel}: {name} (from {sorted(owners) or 'nothing installed'}; station.extras "
                                   f"says {extra or 'a main dependency'})")  # fmt: skip
    assert not missing, "imported but not declared in pyproject.toml for that file:\n" + "\n".join(missing)


def _source_copy(dest: Path) -> Path:
    """The working tree's files (tracked and new, not ignored) and the npm package of uPlot, as a build would see."""
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=ROOT,
                           capture_output=True, check=True).stdout.decode().split("\0")  # fmt: skip
    for rel in filter(None, files):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    uplot = ROOT / "web" / "node_modules" / "uplot"
    if uplot.is_dir():  # else setup.py runs `npm ci` (web/setup.sh installs it for the tests)
        shutil.copytree(uplot, dest / "web" / "node_modules" / "uplot")
    return dest


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_a_plain_install_runs_the_main_job_from_an_empty_folder(tmp_path):
    src = _source_copy(tmp_path / "src")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                               capture_output=True, text=True, check=True).stdout.strip())  # fmt: skip
    (site / "_dependencies.pth").write_text(sysconfig.get_path("purelib") + "\n")  # the dev venv's third parties
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--no-build-isolation",
                    str(src)], check=True, env=env, cwd=tmp_path)  # fmt: skip
    shutil.rmtree(src)  # nothing may come from the source tree from here on

    files = subprocess.run([str(py), "-c", "import importlib.metadata as m; "
                            "print('\\n'.join(str(f) for f in m.files('piga-station')))"],
                           capture_output=True, text=True, check=True, env=env, cwd=tmp_path).stdout  # fmt: skip
    installed = {Path(f).parts[0] for f in files.split()} - {".."}  # ../../bin/station: the console script
    assert {name for name in installed if not name.endswith(".dist-info")} == set(PACKAGES)

    where = subprocess.run(
        [str(py), "-c", "import station.defaults as d, web.app as w, station.cli as app, json; "
         "print(json.dumps([str(d.config_dir()), str(w.UPLOT), app.__file__]))"],
        capture_output=True, text=True, check=True, env=env, cwd=tmp_path,
    ).stdout  # fmt: skip
    config_dir, uplot, app_file = (Path(p) for p in json.loads(where))
    assert config_dir == site / "station" / "_config"
    assert (config_dir / "procedures" / "integral_precession.toml").is_file()
    assert (config_dir / "eds" / "vibration_table_servo.eds").is_file()
    assert uplot == site / "web" / "vendor" / "uplot" and (uplot / "uPlot.iife.min.js").stat().st_size > 10_000
    assert app_file.is_relative_to(site)

    empty = tmp_path / "empty"
    empty.mkdir()
    for words, planned in (
        (["integral_precession"], "integral_precession"),
        (["multiposition", "--station", "dual-sim", "--twin", "multiposition"], "multiposition"),
    ):
        dry = subprocess.run([str(venv / "bin" / "station"), "run", *words, "--out", "dry", "--dry-run"], cwd=empty,
                             env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
        assert dry.returncode == 0 and dry.stdout.startswith(f"dry run of {planned}:"), dry.stdout + dry.stderr
    run = subprocess.run([str(venv / "bin" / "station"), "calibrate", "--out", "out"], cwd=empty, env=env,
                         capture_output=True, text=True, timeout=800)  # fmt: skip
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    out = empty / "out"
    (report,) = out.glob("report-*.html")
    html = report.read_text()
    assert "Provenance" in html and "station-sim" in html
    (export,) = out.glob("session-*")
    doc = json.loads((export / "session.json").read_text())
    assert doc["provenance"]["station_id"] == "station-sim" and doc["provenance"]["simulated"] is True
    assert doc["provenance"]["software_version"] == importlib.metadata.version("piga-station")  # no git checkout
    assert len((export / "points.csv").read_text().splitlines()) == 41  # seed 000's 40 points and the header
    _the_main_job_stored_identified_and_reported(run.stdout, out)


def _the_main_job_stored_identified_and_reported(printed: str, out: Path) -> None:
    assert re.search(r"^\s+kzz\s+= ", printed, re.M) and "u = " in printed and "U = " in printed  # value, u, U = k u
    with SessionStore(out / "station.sqlite") as store:
        (session,) = store.sessions()
        assert session["n_points"] == 40 and session["status"] == "finished"
        results = {r["method"]: r["result"] for r in store.results(session["uid"])}
    integral = results["integral"]["coefficients"]
    truth = {"kz": 0.56, "kzz": 6e-6, "ky": 5e-6, "k3": 7e-7}  # the embedded default twin's instrument
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
    assert next(out.glob("certificate-*.pdf")).read_bytes().startswith(b"%PDF")
    assert "SIMULATED" in next(out.glob("certificate-*.html")).read_text()
    report = next(out.glob("report-*.html")).read_text()
    assert "<svg" in report and "Timing capture" in report and "http" not in report.split("<svg")[0]
    result = json.loads(next(out.glob("result-*.json")).read_text())
    assert result["baseline"]["coefficients"]["kz"]["value"] is None
