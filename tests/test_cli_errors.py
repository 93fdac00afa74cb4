"""Every `station` subcommand given bad paths or options ends with one clear line on stderr, never a traceback.

Each case runs `station` in this process (an exception that escapes main() fails the test; pytest's stdin
is not a terminal, as in a script or CI) and asserts exit status 2 and the message naming the option or
path and what is allowed; two run as `python -m station.cli.cli` to show the shell's view. `panel-user` asks before
replacing a password and requires --role.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from station.cli.cli import build_parser
from station.cli.console import CONFIG_DIR

REPO = Path(__file__).resolve().parents[1]
CLI_TIMEOUT_S = 90.0  # a loaded 2-core machine imports the CLI in a few seconds


def station(*args: str, env: dict | None = None, stdin: str | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "station.cli.cli", *args], capture_output=True, text=True, cwd=REPO,
                          timeout=CLI_TIMEOUT_S, input=stdin or "", env=os.environ | (env or {}))  # fmt: skip


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bad")
    (d / "afile").write_text("not a directory\n")
    (d / "broken.toml").write_text("this is = = not toml\n")
    (d / "unknown.toml").write_text('procedure = "no.such.procedure"\n[params]\n')
    (d / "badparam.toml").write_text('procedure = "integral_precession"\n[params]\nwindow_s = -5\n')
    return d


CASES = [
    # (arguments with {d} for the bad-input directory, what the message must say)
    ("calibrate --speed 0 --out {d}/o", "--speed: 0 is not allowed"),
    ("calibrate --speed -3 --out {d}/o", "finite number > 0"),
    ("calibrate --speed nan --out {d}/o", "--speed: nan is not allowed"),
    ("calibrate --speed fast", "'fast' is not a number"),
    ("calibrate --seed x", "--seed: invalid int value"),
    ("calibrate --station {d}/nope.toml --out {d}/o", "nope.toml"),
    ("calibrate --station {d}/broken.toml --out {d}/o", "broken.toml"),
    ("calibrate --twin {d}/nope.toml --out {d}/o --dry-run", "twin config"),
    ("calibrate --procedure {d}/nope.toml --out {d}/o", "no such file"),
    ("calibrate --out {d}/afile --dry-run", "afile"),
    ("calibrate --bogus-option", "unrecognized arguments: --bogus-option"),
    ("run {d}/unknown.toml --out {d}/o", "unknown procedure 'no.such.procedure'"),
    ("run {d}/badparam.toml --out {d}/o --dry-run", "window_s"),
    ("run {d}/broken.toml --out {d}/o", "not valid TOML"),
    ("run", "the following arguments are required: procedure_file"),
    ("resume NOSUCH --out {d}/o", "no session 'NOSUCH'"),
    ("serve --speed 0 --out {d}/o", "--speed: 0 is not allowed"),
    ("serve --token-env STATION_TEST_UNSET_VAR --out {d}/o", "STATION_TEST_UNSET_VAR"),
    ("serve --station {d}/nope.toml --out {d}/o", "nope.toml"),
    ("serve --control garbage --out {d}/o", "--control: 'garbage' is not an endpoint: allowed tcp://HOST:PORT"),
    ("calibrate --telemetry 127.0.0.1:5561 --out {d}/o", "--telemetry: '127.0.0.1:5561' is not an endpoint"),
    ("identify {d}/nope", "not a directory"),
    ("identify {d}", "session.json"),
    ("identify {d} --method nope", "invalid choice: 'nope'"),
    ("certificate {d}/nope --out {d}/c", "no session directory there; for a stored session pass its uid and --db"),
    ("certificate NOPE --db {d}/nope.sqlite --out {d}/c", "nope.sqlite: no session store there"),
    ("simulate {d}/afile", "afile exists; pass --overwrite to replace it"),
    ("simulate {d}/sim --twin {d}/nope.toml", "no such file"),
    ("sessions --db {d}/nope.sqlite", "no session store there"),
    ("export NOSUCH {d}/exp --db {d}/nope.sqlite", "no session store there"),
    ("import {d}/nope --db {d}/x.sqlite", "not a directory"),
    ("import {d} --db {d}/x.sqlite", "session.json"),
    ("gap {d}/nope --json {d}/g.json", "not a directory"),
    ("gap --bogus", "required"),
    ("gap-validate --snr abc", "--snr: 'abc' is not a number"),
    ("gap-validate --snr 0", "--snr: 0 is not allowed: > 0 expected"),
    ("gap-validate --reps -1", "--reps: -1 is not allowed: > 0 expected"),
    ("sync {d}/nope.sqlite --to postgresql://station@127.0.0.1:1/db --arrays {d}/arrays", "no session store there"),
    ("sync", "the following arguments are required"),
    ("panel --config {d}/nope.toml", "no such file"),
    ("panel --config {d}/broken.toml", "not valid TOML"),
    ("panel --port 99999", "--port: '99999' is not allowed: a TCP port is an integer 1-65535"),
    ("panel-user add bob --users {d}/u.json --password-env PW", "--role is required"),
    ("panel-user add bob --role operator --users {d}/u.json", "no terminal to ask the password on"),
    ("panel-user add bob --role admin --users {d}/u.json", "invalid choice: 'admin'"),
    ("panel-user remove nobody --users {d}/u.json", "no user 'nobody'"),
    ("panel-user list --users {d}/afile", "not a users file"),
    ("panel-user frobnicate", "invalid choice: 'frobnicate'"),
]


def run_main(argv: list[str], capsys) -> tuple[int, str]:
    """`station ARGV` in this process: (exit status, stderr). An escaping exception fails the test."""
    from station.cli.cli import main

    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code
    return code, capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), CASES, ids=[c[0].split(" {")[0] for c in CASES])
def test_bad_options_give_one_clear_error_and_no_traceback(bad, argv, message, capsys, monkeypatch):
    monkeypatch.setenv("PW", "a long enough password")
    code, err = run_main(argv.format(d=bad).split(), capsys)
    assert code == 2, (code, err)
    assert message in err, err
    assert "error" in err.strip().splitlines()[-1]


@pytest.mark.parametrize("argv", ["calibrate --speed 0", "panel-user add bob --role viewer --users {d}/u.json"])
def test_from_a_shell_the_error_is_one_line_and_no_traceback(bad, argv):
    """The same through `python -m station.cli.cli` with stdin not a terminal, as a script or CI runs it: the error
    (after argparse's usage, if argparse refused) is the last line."""
    r = station(*argv.format(d=bad).split())
    assert r.returncode == 2 and "Traceback" not in r.stderr + r.stdout, r.stderr
    last = r.stderr.strip().splitlines()[-1]  # argparse shows the usage first
    assert last.startswith("station ") and ": error: " in last, r.stderr


def test_every_subcommand_is_covered_and_every_option_has_help():
    """The cases above reach every subcommand, and `--help` explains every option of every subcommand."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    covered = {c[0].split()[0] for c in CASES}
    assert set(sub.choices) <= covered, set(sub.choices) - covered
    from station.gap.api import build_parser as gap_parser

    parsers = {**sub.choices, "gap": gap_parser()}  # `station gap` parses its own arguments (station/gap/api.py)
    for name, p in parsers.items():
        if name == "gap-validate":  # its parser lives inside station.gap.validate.main: its --help is checked below
            continue
        for action in p._actions:
            if action.dest != "help":
                assert action.help, f"station {name}: {action.option_strings or action.dest} has no help text"


def test_gap_validate_explains_every_option(capsys):
    """Its parser lives in station.gap.validate.main: every option in its --help has text, on its line or the next."""
    from station.gap.validate import main as validate_main

    with pytest.raises(SystemExit):
        validate_main(["--help"])
    text = capsys.readouterr().out
    lines = text[text.index("options:") :].splitlines()[1:]
    for i, line in enumerate(lines):
        option = re.match(r"^  (-\S.*?)(?:\s{2,}(\S.*))?$", line)
        if option:
            following = lines[i + 1] if i + 1 < len(lines) else ""
            explained = option.group(2) or re.match(r"^ {10,}\S", following)
            assert explained, f"station gap-validate {option.group(1)} has no help text"


def test_panel_user_asks_before_replacing_a_password(tmp_path):
    users = str(tmp_path / "users.json")
    env = {"PW": "first long password", "PW2": "second long password"}
    assert station("panel-user", "add", "olga", "--role", "operator", "--users", users, "--password-env", "PW",
                   env=env).returncode == 0  # fmt: skip
    # Without a terminal to ask on, a replacement needs --replace; the old password still works.
    r = station("panel-user", "add", "olga", "--role", "viewer", "--users", users, "--password-env", "PW2", env=env)
    assert r.returncode == 2 and "already exists" in r.stderr and "--replace" in r.stderr, r.stderr
    from web.users import UserBook

    assert UserBook(users).verify("olga", env["PW"]).role == "operator"
    r = station("panel-user", "add", "olga", "--role", "viewer", "--users", users, "--password-env", "PW2",
                "--replace", env=env)  # fmt: skip
    assert r.returncode == 0 and "replaced" in r.stdout, r.stderr
    assert UserBook(users).verify("olga", env["PW"]) is None
    assert UserBook(users).verify("olga", env["PW2"]).role == "viewer"


def test_panel_user_on_a_terminal_keeps_the_password_unless_the_operator_says_yes(tmp_path, monkeypatch, capsys):
    from station.cli.cli import main
    from web.users import UserBook

    users = str(tmp_path / "users.json")
    monkeypatch.setenv("PW", "first long password")
    assert main(["panel-user", "add", "olga", "--role", "operator", "--users", users, "--password-env", "PW"]) == 0
    monkeypatch.setattr(sys.stdin, "isatty", lambda: True)
    monkeypatch.setenv("PW", "second long password")
    for answer, kept in (("n", True), ("", True), ("yes", False)):
        monkeypatch.setattr("builtins.input", lambda prompt, a=answer: a)
        code = main(["panel-user", "add", "olga", "--role", "operator", "--users", users, "--password-env", "PW"])
        assert code == (1 if kept else 0)
        assert (UserBook(users).verify("olga", "first long password") is not None) == kept
    assert "left as it was" in capsys.readouterr().err


def test_a_missing_station_file_is_named_as_typed(bad, capsys):
    for command in ("calibrate", "serve"):
        code, err = run_main([command, "--station", f"{bad}/nope.toml", "--out", f"{bad}/o"], capsys)
        assert code == 2
        stations = ", ".join(sorted(p.stem for p in (CONFIG_DIR / "stations").glob("*.toml")))
        assert err.strip().splitlines()[-1] == (f"station {command}: error: --station {bad}/nope.toml: no such file, "
                                                "and no shipped station configuration of that name (a path, or one "
                                                f"of: {stations})")  # fmt: skip
        assert "not allowed" not in err and "readable file" not in err


def test_sessions_has_a_header_and_export_names_its_option(tmp_path, capsys):
    from station.interchange import write_session
    from station.twin.config import TwinConfig
    from station.twin.plan import multiposition_plan
    from station.twin.session_sim import simulate_session

    plan = multiposition_plan([0.0, 180.0], [10.0], window_s=20.0)
    write_session(simulate_session(plan, TwinConfig(), seed=1), tmp_path / "s")
    db = str(tmp_path / "db.sqlite")
    assert run_main(["import", str(tmp_path / "s"), "--db", db], capsys)[0] == 0
    capsys.readouterr()
    from station.cli.cli import main

    assert main(["sessions", "--db", db]) == 0
    header, row = capsys.readouterr().out.splitlines()
    assert header.split() == ["uid", "created", "(UTC)", "procedure", "status", "points", "measurements"]
    assert len(header) == len(row) and header.index("status") == row.rindex("imported"), (header, row)
    uid = row.split()[0]
    (tmp_path / "exp").mkdir()
    code, err = run_main(["export", uid, str(tmp_path / "exp"), "--db", db], capsys)
    assert code == 2 and err.strip().endswith(f"{tmp_path / 'exp'} exists; pass --overwrite to replace it"), err
    assert run_main(["export", uid, str(tmp_path / "exp"), "--db", db, "--overwrite"], capsys)[0] == 0
