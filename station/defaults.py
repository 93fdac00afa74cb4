"""Where the shipped defaults are: station files, procedure files, the drive's EDS, instrument files, the panel's
configuration (the source tree's config/ directory).

An installed package carries them as the package `piga_station_config` (setup.py copies config/ into the wheel
at build time) and finds them through importlib.resources; a source checkout (the tests, an editable install)
uses config/ itself.
"""

from __future__ import annotations

import importlib.resources
from functools import cache
from pathlib import Path

PACKAGE = "piga_station_config"
SOURCE_CONFIG = Path(__file__).resolve().parents[1] / "config"


@cache
def config_dir() -> Path:
    """The directory of the shipped defaults: the installed package's data, else the source tree's config/."""
    try:
        shipped = importlib.resources.files(PACKAGE)
    except ModuleNotFoundError:
        return SOURCE_CONFIG
    return Path(str(shipped))


def config_file(*parts: str) -> Path:
    """A shipped default by its path under config/, e.g. config_file("procedures", "integral_precession.toml")."""
    return config_dir().joinpath(*parts)
