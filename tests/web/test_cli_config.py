"""`station panel-user`, `station panel` refusing bad configuration, and the panel configuration file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from station.cli.cli import main
from web.config import PanelConfig, PanelConfigError
from web.users import UserBook

STATION = """
[[stations]]
name = "sim"
control = "tcp://127.0.0.1:5560"
telemetry = "tcp://127.0.0.1:5561"
store = "out/station.sqlite"
reports = "out"
"""


def test_panel_user_add_list_remove(tmp_path: Path, monkeypatch, capsys):
    users = tmp_path / "users.json"
    monkeypatch.setenv("PANEL_PW", "a long enough password")
    assert (
        main(["panel-user", "add", "olga", "--role", "operator", "--users", str(users), "--password-env", "PANEL_PW"])
        == 0
    )
    assert (
        main(["panel-user", "add", "victor", "--role", "viewer", "--users", str(users), "--password-env", "PANEL_PW"])
        == 0
    )
    capsys.readouterr()
    assert main(["panel-user", "list", "--users", str(users)]) == 0
    assert capsys.readouterr().out.split() == ["olga", "operator", "victor", "viewer"]
    assert UserBook(users).verify("olga", "a long enough password").role == "operator"
    assert UserBook(users).verify("olga", "a wrong password") is None
    assert "a long enough password" not in users.read_text()
    assert main(["panel-user", "remove", "victor", "--users", str(users)]) == 0
    assert [u.name for u in UserBook(users).list()] == ["olga"]


@pytest.mark.parametrize(
    ("args", "env", "message"),
    [
        (["add", "olga", "--role", "operator", "--password-env", "PANEL_PW"], "short", "password too short"),
        (
            ["add", "bad name", "--role", "viewer", "--password-env", "PANEL_PW"],
            "long enough pw",
            "user name 'bad name'",
        ),
        (
            ["add", "olga", "--role", "viewer", "--password-env", "UNSET_VAR"],
            None,
            "UNSET_VAR: that environment variable is not set",
        ),
        (["add", "olga", "--password-env", "PANEL_PW"], "long enough pw", "--role is required"),
        (["remove", "nobody"], None, "no user 'nobody'"),
    ],
)
def test_panel_user_refuses_bad_input_with_a_message(tmp_path, monkeypatch, capsys, args, env, message):
    if env is not None:
        monkeypatch.setenv("PANEL_PW", env)
    assert main(["panel-user", *args, "--users", str(tmp_path / "users.json")]) == 2
    assert message in capsys.readouterr().err


def test_a_corrupt_users_file_is_refused(tmp_path, capsys):
    users = tmp_path / "users.json"
    users.write_text(json.dumps({"users": {"olga": {"role": "admin", "hash": "x"}}}))
    assert main(["panel-user", "list", "--users", str(users)]) == 2
    assert "every user needs a role" in capsys.readouterr().err


def test_the_example_configuration_is_valid_and_binds_to_localhost():
    config = PanelConfig.from_toml(Path(__file__).resolve().parents[2] / "config" / "panel.toml")
    assert config.host == "127.0.0.1" and config.stations[0].name == "sim"
    assert "out/" in str(config.users)  # outside the repository's tracked files


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("port = 99999\n" + STATION, "port: Input should be less than or equal to 65535"),
        ("colour = 'red'\n" + STATION, "colour: Extra inputs are not permitted"),
        ("", "stations: Field required"),
        (STATION + STATION, "station names must be unique"),
        (STATION.replace("tcp://127.0.0.1:5560", "http://x"), "stations.0.control: String should match pattern"),
        (STATION.replace('"sim"', '"bad name"'), "stations.0.name"),
        ("port = \n", "not valid TOML"),
        ("twin = 'no/such.toml'\n" + STATION, "no such file"),
    ],
)
def test_bad_configuration_is_refused_naming_the_key(tmp_path, capsys, text, message):
    path = tmp_path / "panel.toml"
    path.write_text(text)
    with pytest.raises(PanelConfigError, match=None) as err:
        PanelConfig.from_toml(path)
    assert message in str(err.value) and str(path) in str(err.value)
    assert main(["panel", "--config", str(path)]) == 2
    assert message in capsys.readouterr().err


def test_panel_with_a_missing_configuration(tmp_path, capsys):
    assert main(["panel", "--config", str(tmp_path / "none.toml")]) == 2
    assert "none.toml: no such file" in capsys.readouterr().err
