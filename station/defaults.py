"""Where the shipped defaults are: station files, procedure files, the drive's EDS, instrument files, the panel's
configuration (the source tree's config/ directory).

An installed package carries them as station/_config, data of the station package (setup.py copies config/ into
the wheel at build time), found through importlib.resources; a source checkout (the tests, an editable install)
uses config/ itself.

A station, procedure or twin file is taken by path or by the name of a shipped one (`shipped_file`): `--station
tumble-sim` is config/stations/tumble-sim.toml, `station run integral_precession` config/procedures/
integral_precession.toml, from any folder.
"""

from __future__ import annotations

import importlib.resources
from functools import cache
from pathlib import Path

from station.errors import InputError

SHIPPED = "_config"  # under the installed station package
SOURCE_CONFIG = Path(__file__).resolve().parents[1] / "config"


@cache
def config_dir() -> Path:
    """The directory of the shipped defaults: the installed package's data, else the source tree's config/."""
    shipped = importlib.resources.files("station") / SHIPPED
    return Path(str(shipped)) if shipped.is_dir() else SOURCE_CONFIG


def config_file(*parts: str) -> Path:
    """A shipped default by its path under config/, e.g. config_file("procedures", "integral_precession.toml")."""
    return config_dir().joinpath(*parts)


# The shipped files taken by name: their folder under config/ and what the operator calls one.
SHIPPED_KINDS = {"stations": "station configuration", "procedures": "procedure file", "twins": "twin configuration"}


def shipped_names(kind: str) -> list[str]:
    """The names of the shipped files of a kind (stations, procedures, twins): their stems."""
    return sorted(path.stem for path in config_file(kind).glob("*.toml"))


def shipped_file(value: str | Path, kind: str, option: str) -> Path:
    """The file an option names: a path that exists is that path, else the shipped file of that name
    (config/KIND/VALUE.toml); anything else is an InputError naming the option, the value and the names allowed."""
    path = Path(value)
    if path.exists():
        return path
    shipped = config_file(kind, f"{value}.toml")
    if path.name == str(value) and shipped.is_file():
        return shipped
    raise InputError(
        f"{option} {value}: no such file, and no shipped {SHIPPED_KINDS[kind]} of that name "
        f"(a path, or one of: {', '.join(shipped_names(kind))})"
    )
