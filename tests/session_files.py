"""Edits of a piga-session/1 directory that the interchange tests share."""

import csv
from pathlib import Path


def set_cell(session_dir: Path, row: int, column: str, value: str) -> None:
    """Replace one cell of points.csv (row 2 is the first point, as the error messages count)."""
    path = session_dir / "points.csv"
    rows = list(csv.DictReader(path.open()))
    rows[row - 2][column] = value
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
