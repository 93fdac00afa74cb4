"""Where a session came from: software, station, operator, host, time, simulated or real, seed, instrument, customer.

Every session carries a `provenance` record (session.json and the store). Its keys are PROVENANCE_KEYS;
certificates and reports read it as a plain dict. On a real station the instrument serial number must be
given (procedure file or command line): `make_provenance` refuses an empty one.
"""

from __future__ import annotations

import getpass
import importlib.metadata
import os
import socket
import subprocess
from datetime import UTC, datetime
from functools import cache
from pathlib import Path
from typing import Any

from station.errors import InputError

PACKAGE = "piga-station"
PROVENANCE_KEYS = (
    "software_version",
    "station_id",
    "operator",
    "host",
    "created_utc",
    "simulated",
    "seed",
    "instrument_serial",
    "customer",
)
SIMULATED_SERIAL = "SIM-PIGA-0001"  # the simulated instrument's serial: a default only on a simulated station


class ProvenanceError(InputError):
    """A session that cannot say where it came from (a real station without an instrument serial number)."""


@cache
def software_version() -> str:
    """The package version, plus the git commit of the source tree when there is one ("0.1.0+g1a224dc")."""
    try:
        version = importlib.metadata.version(PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    source = Path(__file__).resolve().parents[1]
    if (source / ".git").exists():

        def git(*args: str) -> str:
            run = subprocess.run(["git", "-C", str(source), *args], capture_output=True, text=True, timeout=5)
            run.check_returncode()
            return run.stdout.strip()

        try:
            commit = git("rev-parse", "--short=12", "HEAD")
            dirty = git("status", "--porcelain", "--untracked-files=no")
        except (OSError, subprocess.SubprocessError):
            return version
        if commit:
            return f"{version}+g{commit}" + (".dirty" if dirty else "")
    return version


def os_user() -> str:
    """The user at the console."""
    try:
        return getpass.getuser()
    except (OSError, KeyError):
        return str(os.getuid()) if hasattr(os, "getuid") else "unknown"


def make_provenance(
    *,
    station_id: str,
    simulated: bool,
    instrument_serial: str = "",
    seed: int | None = None,
    operator: str | None = None,
    customer: str | None = None,
    created_utc: str | None = None,
) -> dict[str, Any]:
    """The provenance record of a new session; ProvenanceError for a real station without an instrument serial."""
    serial = (instrument_serial or "").strip()
    if not serial:
        if not simulated:
            raise ProvenanceError(
                f"station {station_id!r} is a real station: the instrument serial number is required "
                "(instrument_serial in the procedure file, or --serial)"
            )
        serial = SIMULATED_SERIAL
    return local_provenance(
        station_id=station_id, operator=operator or None, customer=customer or None, created_utc=created_utc,
        simulated=bool(simulated),
        seed=seed if simulated else None, instrument_serial=serial,
    )  # fmt: skip


def unknown_provenance(**known: Any) -> dict[str, Any]:
    """The provenance of a session recorded without one (an older store, a directory with only physics.md's
    fields): every key present, None where it is not known."""
    return {k: known.get(k) for k in PROVENANCE_KEYS}


def local_provenance(**known: Any) -> dict[str, Any]:
    """What this process knows without a station: software, operator, host, time (and any `known` keys)."""
    here = {
        "software_version": software_version(),
        "operator": os_user(),
        "host": socket.gethostname(),
        "created_utc": datetime.now(UTC).isoformat(timespec="milliseconds"),
    }
    return unknown_provenance(**(here | {k: v for k, v in known.items() if v is not None}))


def check_provenance(doc: Any, where: str) -> dict[str, Any]:
    """A provenance object read from a file: an object whose known keys have the right types; extra keys kept."""
    if not isinstance(doc, dict):
        raise ProvenanceError(
            f"{where}: 'provenance' = {doc!r}: expected an object with keys {', '.join(PROVENANCE_KEYS)}"
        )
    types: dict[str, tuple[type, ...]] = {k: (str,) for k in PROVENANCE_KEYS}
    types["simulated"] = (bool,)
    types["seed"] = (int,)
    out = unknown_provenance() | doc
    for key, allowed in types.items():
        v = out[key]
        if v is not None and (not isinstance(v, allowed) or (key == "seed" and isinstance(v, bool))):
            names = " or ".join(t.__name__ for t in allowed)
            raise ProvenanceError(f"{where}: provenance.{key} = {v!r}: expected {names} or null")
    return out
