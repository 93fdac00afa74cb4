"""A plain install (no [fleet], [web] or [notebook]) runs the bench controller's main path, and a command that
needs a missing extra says which one in one line and exits 2, no traceback; `station.open_store` without
[notebook] raises an ImportError naming the pip command.

Each case runs in a subprocess whose import system refuses the modules of the extras (station.extras.EXTRAS),
as an interpreter without them installed would.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from station.extras import EXTRAS
from station.store import SessionStore

REPO = Path(__file__).resolve().parents[1]
TIMEOUT_S = 300.0  # a loaded 2-core machine: the main path below simulates, identifies and diagnoses a session
REFUSE = """
import importlib.abc, json, sys

class Refuse(importlib.abc.MetaPathFinder):
    refused = set(json.loads(sys.argv[1]))

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in self.refused:
            raise ModuleNotFoundError(f"No module named {name!r} (refused by tests/test_extras.py)", name=name)
        return None

sys.meta_path.insert(0, Refuse())
"""
STATION = "from station.cli.cli import main\nsys.exit(main(json.loads(sys.argv[2])))"
MAIN_PATH = """
from station.cli.cli import main
for argv in json.loads(sys.argv[2]):
    print("station", *argv, flush=True)
    assert main(argv) == 0, argv
"""


def without(extras: tuple[str, ...], code: str, argv: object, cwd: Path) -> subprocess.CompletedProcess:
    """Python running REFUSE + `code` in `cwd` with the modules of `extras` refused; argv[2] is `argv` as JSON."""
    refused = [m for extra in extras for m in EXTRAS[extra]]
    env = os.environ | {"PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-c", REFUSE + code, json.dumps(refused), json.dumps(argv)], cwd=cwd,
                          capture_output=True, text=True, timeout=TIMEOUT_S, env=env)  # fmt: skip


def test_the_main_path_runs_without_any_extra(tmp_path):
    session, db = str(tmp_path / "session"), str(tmp_path / "station.sqlite")
    steps = [
        ["calibrate", "--dry-run", "--out", str(tmp_path / "out")],
        ["run", "tumble", "--station", "tumble-sim", "--dry-run"],
        ["simulate", session, "--seed", "3"],
        ["identify", session, "--json", str(tmp_path / "identified.json")],
        ["gap", session, "--json", str(tmp_path / "gap.json")],
        ["import", session, "--db", db],
        ["sessions", "--db", db],
    ]  # fmt: skip
    run = without(tuple(EXTRAS), MAIN_PATH, steps, tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "kzz" in json.loads((tmp_path / "identified.json").read_text())["coefficients"]
    assert (tmp_path / "gap.json").is_file()
    with SessionStore(db) as store:
        (stored,) = store.sessions()
    assert stored["n_points"] == 40 and stored["uid"] in run.stdout  # `sessions` listed what `import` stored

    uid = stored["uid"]
    run = without(tuple(EXTRAS), MAIN_PATH, [["export", uid, str(tmp_path / "exported"), "--db", db]], tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    assert len((tmp_path / "exported" / "points.csv").read_text().splitlines()) == 41


COMMANDS = {  # the command line, what needs the extra (as the message names it) and the extra
    "panel-user add": (
        "panel-user add ada --role operator --users {tmp}/users.toml --password-env PANEL_PASSWORD",
        "station panel-user",
        "web",
    ),
    "panel": ("panel --port 8999", "station panel", "web"),
    "sync": ("sync {store} --to postgresql://station@127.0.0.1:1/none --arrays {tmp}/arrays", "station sync", "fleet"),
    "serve --sync-to": (
        "serve --out {tmp}/out --control inproc://control --telemetry inproc://telemetry "
        "--sync-to postgresql://station@127.0.0.1:1/none --sync-arrays {tmp}/arrays",
        "station serve",
        "fleet",
    ),
    "gap-validate on dask": (
        "gap-validate --executor dask --scheduler tcp://127.0.0.1:1 --design seed000 --snr 5 --reps 1 --nulls 0",
        "the dask executor",
        "fleet",
    ),
}


@pytest.mark.parametrize("command", COMMANDS)
def test_a_command_without_its_extra_says_which_in_one_line(tmp_path, command):
    words, what, extra = COMMANDS[command]
    argv = [w.format(tmp=tmp_path, store=_store(tmp_path)) for w in words.split()]
    run = without((extra,), STATION, argv, tmp_path)
    assert run.returncode == 2, run.stdout[-2000:] + run.stderr[-2000:]
    modules = "|".join(EXTRAS[extra])
    pip = rf"pip install 'piga-station\[{extra}\]'"
    assert re.fullmatch(rf"{what} needs the \[{extra}\] extra \(({modules}) is not installed\): {pip}\n", run.stderr), (
        run.stderr[-2000:]
    )
    made = [tmp_path / "users.toml", tmp_path / "arrays", tmp_path / "out"]  # serve would make out/ first
    assert not [p for p in made if p.exists()]  # refused before anything was done


def _store(tmp_path: Path) -> str:
    path = tmp_path / "station.sqlite"
    SessionStore(path).close()
    return str(path)


def test_open_store_without_the_notebook_extra_names_the_pip_command(tmp_path):
    code = (
        "import station\ntry:\n    station.open_store(json.loads(sys.argv[2]))\nexcept ImportError as e:\n    print(e)"
    )
    run = without(("notebook",), code, _store(tmp_path), tmp_path)
    assert run.returncode == 0 and run.stderr == "", run.stderr[-2000:]
    assert run.stdout.startswith("station.open_store (the notebook API) needs the [notebook] extra (pandas ")
    assert run.stdout.rstrip().endswith("pip install 'piga-station[notebook]'")
