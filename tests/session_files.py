"""Edits of a piga-session/1 directory that the interchange tests share, and the check of a whole refusal."""

import csv
from pathlib import Path

import pytest

from station.cli.cli import main
from station.interchange import SessionFormatError, read_session
from station.store import SessionStore


def set_cell(session_dir: Path, row: int, column: str, value: str) -> None:
    """Replace one cell of points.csv (row 2 is the first point, as the error messages count)."""
    path = session_dir / "points.csv"
    rows = list(csv.DictReader(path.open()))
    rows[row - 2][column] = value
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def refused(directory: Path, tmp_path: Path, *parts: str) -> str:
    """The directory is refused naming each of `parts`, and `station import` of it exits 2 and stores nothing (no
    session, no file beside the store); the refusal's message."""
    with pytest.raises(SessionFormatError) as info:
        read_session(directory)
    message = str(info.value)
    for p in parts:
        assert p in message, message
    db = tmp_path / "store.sqlite"
    assert main(["import", str(directory), "--db", str(db)]) == 2
    with SessionStore(db) as store:
        assert store.sessions() == []
    assert not [p for p in (tmp_path / "store.sqlite.raw").glob("*") if not p.name.startswith(".")]
    return message
