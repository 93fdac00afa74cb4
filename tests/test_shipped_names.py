"""Shipped station, procedure and twin files are taken by name from any folder (`station run integral_precession
--station tumble-sim --twin multiposition`); a path that exists is still a path; a value that is neither is one line
naming the option, the value and the names allowed."""

from __future__ import annotations

import pytest

from station.cli.cli import main
from station.defaults import config_dir, shipped_file, shipped_names
from station.engine.registry import load_library, load_procedure_file
from station.errors import InputError


@pytest.fixture
def empty_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_every_procedure_has_a_shipped_file_of_its_own_name(empty_folder) -> None:
    """What `station run --help` promises: the name of a registered procedure runs it from its shipped file."""
    for name in load_library():
        spec, _ = load_procedure_file(shipped_file(name, "procedures", "procedure_file"))
        assert spec.name == name


@pytest.mark.parametrize(
    ("argv", "planned"),
    [
        (["run", "integral_precession.planning"], "integral_precession.planning"),
        (["run", "tumble", "--station", "tumble-sim"], "tumble"),
        (
            ["run", "multiposition.planning", "--station", "dual-sim", "--twin", "multiposition"],
            "multiposition.planning",
        ),
        (["calibrate", "--procedure", "integral_precession.self_alignment"], "integral_precession.self_alignment"),
    ],
)
def test_names_resolve_from_an_empty_folder(empty_folder, argv, planned, capsys) -> None:
    assert main([*argv, "--out", "out", "--dry-run"]) == 0
    assert capsys.readouterr().out.startswith(f"dry run of {planned}:")


def test_a_path_that_exists_is_a_path_before_a_name(empty_folder, capsys) -> None:
    (empty_folder / "tumble-sim").write_text("this is = = not toml\n")  # the shipped tumble-sim.toml is valid
    assert main(["run", "tumble", "--station", "tumble-sim", "--out", "out", "--dry-run"]) == 2
    assert capsys.readouterr().err.startswith("station run: error: tumble-sim: <syntax>")


@pytest.mark.parametrize(("kind", "option"), [("stations", "--station"), ("procedures", "procedure_file"),
                                              ("twins", "--twin")])  # fmt: skip
def test_a_value_that_is_neither_names_the_option_the_value_and_the_names_allowed(empty_folder, kind, option) -> None:
    with pytest.raises(InputError) as caught:
        shipped_file("sub/vibration-sim", kind, option)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"{option} sub/vibration-sim: no such file")
    assert message.endswith(f"(a path, or one of: {', '.join(shipped_names(kind))})")
    assert shipped_names(kind) == sorted(p.stem for p in (config_dir() / kind).glob("*.toml")) != []
