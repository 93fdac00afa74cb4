"""Import and export of the `piga-session/1` interchange format (physics.md).

A session directory holds session.json, points.csv and optionally
raw/<point_id>.npz. Import reads and validates everything before returning,
so a malformed session is refused whole: nothing is half-imported. Every
error names the file, the row, the column, the value and what is allowed.
Export writes to a temporary directory and renames it into place.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from station.errors import InputError
from station.session import PointRecord, RawStreams, Session, StationInfo

FORMAT = "piga-session/1"
COLUMNS = ("point_id", "sequence", "start_s", "position_deg", "freq_hz", "kind", "pulses", "Tm_s", "t1_s", "t2_s", "Np")
OPTIONAL_COLUMNS = ("dut", "pose", "temperature_c")
STATION_KEYS = ("A0_m", "latitude_deg", "g_mps2", "earth_rate_radps", "pulses_per_rev")
RAW_ARRAYS = ("grating_t", "grating_z", "pulse_t")
# t1 + Np T - Tm = t2 holds for a perfect frequency; a frequency error eps_f breaks it by
# eps_f Np T. The real table's frequency stability is < 5e-4 (seed 000 Table 4): allow twice that.
from station import constants
MAX_PERIOD_MISMATCH = 2 * constants.FREQ_STABILITY_MAX
MAX_JSON_BYTES = 64 << 20  # session.json: declarations, provenance, notes; never arrays
MAX_ARRAY_BYTES = 4 << 30  # one decompressed array of an .npz (raw streams of a long window reach ~100 MB)
MEASUREMENTS_DIR = "measurements"
_SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,127}$")
_RESERVED = ("sequence", "key", "arrays_file")
OWN_KEYS = ("format", "station", "notes", "provenance", "measurements", "results")  # the rest of session.json: meta  # the columns of a measurements table before its fields


class SessionFormatError(InputError):
    """A session directory that does not follow piga-session/1."""

    def __init__(self, file: str, message: str, row: int | None = None, column: str | None = None, value=None):
        where = file
        if row is not None:
            where += f" row {row}"
        if column is not None:
            where += f", column {column!r}"
        if value is not None:
            where += f", value {value!r}"
        super().__init__(f"{where}: {message}")
        self.file, self.row, self.column, self.value = file, row, column, value


def _number(text: str, file: str, row: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SessionFormatError(file, "expected a number", row, column, text) from None
    if not math.isfinite(value):
        raise SessionFormatError(file, "expected a finite number (no NaN or inf)", row, column, text)
    return value


def _integer(text: str, file: str, row: int, column: str) -> int:
    value = _number(text, file, row, column)
    if value != int(value) or not text.strip().lstrip("+-").isdigit():
        raise SessionFormatError(file, "expected a whole number", row, column, text)
    return int(value)


def _read_station(path: Path) -> tuple[StationInfo, str, dict]:
    name = "session.json"
    if not path.is_file():
        raise SessionFormatError(name, f"missing: a {FORMAT} directory needs {path}")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SessionFormatError(name, f"not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise SessionFormatError(name, "expected a JSON object at the top level")
    if data.get("format") != FORMAT:
        raise SessionFormatError(name, f"'format' must be {FORMAT!r}", column="format", value=data.get("format"))
    st = data.get("station")
    if not isinstance(st, dict):
        raise SessionFormatError(name, "'station' must be an object with " + ", ".join(STATION_KEYS), column="station")
    values = {}
    for key in STATION_KEYS:
        if key not in st:
            raise SessionFormatError(name, "missing station key", column=f"station.{key}")
        v = st[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
            raise SessionFormatError(name, "expected a positive finite number", column=f"station.{key}", value=v)
        values[key] = v
    if values["pulses_per_rev"] != int(values["pulses_per_rev"]):
        raise SessionFormatError(
            name, "expected a whole number", column="station.pulses_per_rev", value=values["pulses_per_rev"]
        )
    values["pulses_per_rev"] = int(values["pulses_per_rev"])
    notes = data.get("notes", "")
    meta = {k: v for k, v in data.items() if k not in ("format", "station", "notes")}
    return StationInfo(**values), notes if isinstance(notes, str) else json.dumps(notes), meta


def _parse_row(row: dict[str, str], file: str, n: int) -> PointRecord:
    point_id = row["point_id"].strip()
    if not point_id:
        raise SessionFormatError(file, "point_id must not be empty", n, "point_id", row["point_id"])
    kind = row["kind"].strip()
    if kind not in ("static", "vibration"):
        raise SessionFormatError(file, "kind must be 'static' or 'vibration'", n, "kind", row["kind"])
    sequence = _integer(row["sequence"], file, n, "sequence")
    if sequence < 0:
        raise SessionFormatError(file, "sequence must be >= 0", n, "sequence", row["sequence"])
    start = _number(row["start_s"], file, n, "start_s")
    if start < 0:
        raise SessionFormatError(file, "start_s must be >= 0 (session time)", n, "start_s", row["start_s"])
    position = _number(row["position_deg"], file, n, "position_deg")
    freq = _number(row["freq_hz"], file, n, "freq_hz")
    pulses = _integer(row["pulses"], file, n, "pulses")
    if pulses == 0:
        raise SessionFormatError(file, "pulses must be a non-zero signed count", n, "pulses", row["pulses"])
    tm = _number(row["Tm_s"], file, n, "Tm_s")
    if tm <= 0:
        raise SessionFormatError(file, "Tm_s must be > 0", n, "Tm_s", row["Tm_s"])
    extra = {k: row[k] for k in row if k not in COLUMNS and row[k] is not None}
    if kind == "static":
        if freq != 0:
            raise SessionFormatError(file, "a static point must have freq_hz = 0", n, "freq_hz", row["freq_hz"])
        for col in ("t1_s", "t2_s", "Np"):
            if row[col].strip():
                raise SessionFormatError(file, "must be empty for a static point", n, col, row[col])
        return PointRecord(point_id, sequence, start, position, 0.0, "static", pulses, tm, extra=extra)
    if freq <= 0:
        raise SessionFormatError(file, "a vibration point needs freq_hz > 0", n, "freq_hz", row["freq_hz"])
    period = 1.0 / freq
    t1 = _number(row["t1_s"], file, n, "t1_s")
    t2 = _number(row["t2_s"], file, n, "t2_s")
    n_periods = _integer(row["Np"], file, n, "Np")
    slack = period * MAX_PERIOD_MISMATCH
    if not 0 < t1 <= period + slack:
        raise SessionFormatError(file, f"t1_s must lie in (0, T], T = {period:.6g} s", n, "t1_s", row["t1_s"])
    if not 0 <= t2 < period + slack:
        raise SessionFormatError(file, f"t2_s must lie in [0, T), T = {period:.6g} s", n, "t2_s", row["t2_s"])
    if n_periods < 1:
        raise SessionFormatError(file, "Np must be >= 1", n, "Np", row["Np"])
    if t1 >= tm:
        raise SessionFormatError(file, f"t1_s must be before Tm_s = {tm}", n, "t1_s", row["t1_s"])
    spanned = tm - t1 + t2
    if abs(spanned - n_periods * period) > MAX_PERIOD_MISMATCH * n_periods * period:
        raise SessionFormatError(
            file,
            f"inconsistent times: Tm - t1 + t2 = {spanned:.6f} s but Np T = {n_periods * period:.6f} s "
            f"(allowed relative mismatch {MAX_PERIOD_MISMATCH:g})",
            n,
            "Np",
            row["Np"],
        )
    return PointRecord(point_id, sequence, start, position, freq, "vibration", pulses, tm, t1, t2, n_periods, extra)


def _read_points(path: Path) -> list[PointRecord]:
    name = "points.csv"
    if not path.is_file():
        raise SessionFormatError(name, f"missing: a {FORMAT} directory needs {path}")
    try:
        with path.open(newline="") as fh:
            reader = csv.DictReader(fh)
            header = reader.fieldnames or []
            missing = [c for c in COLUMNS if c not in header]
            if missing:
                raise SessionFormatError(
                    name, f"missing column(s) {', '.join(missing)}; header must include {','.join(COLUMNS)}", 1
                )
            points, seen = [], {}
            for n, row in enumerate(reader, start=2):
                if None in row or any(v is None for v in row.values()):
                    raise SessionFormatError(name, f"expected {len(header)} fields", n)
                p = _parse_row(row, name, n)
                if p.point_id in seen:
                    raise SessionFormatError(
                        name, f"duplicate point_id (first on row {seen[p.point_id]})", n, "point_id", p.point_id
                    )
                seen[p.point_id] = n
                points.append(p)
    except UnicodeDecodeError as exc:
        raise SessionFormatError(name, f"not UTF-8 text ({exc})") from None
    except csv.Error as exc:
        raise SessionFormatError(name, f"malformed CSV ({exc})") from None
    if not points:
        raise SessionFormatError(name, "no points")
    return points


def _read_raw(raw_dir: Path, ids: set[str]) -> dict[str, RawStreams]:
    raws: dict[str, RawStreams] = {}
    if not raw_dir.is_dir():
        return raws
    for path in sorted(raw_dir.glob("*.npz")):
        name = f"raw/{path.name}"
        pid = path.stem
        if pid not in ids:
            raise SessionFormatError(name, "no point with this point_id in points.csv", value=pid)
        try:
            with np.load(path, allow_pickle=False) as npz:
                arrays = {k: np.array(npz[k]) for k in npz.files}
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            raise SessionFormatError(name, f"not a readable .npz archive ({exc})") from None
        for key in RAW_ARRAYS:
            if key not in arrays:
                raise SessionFormatError(name, f"missing array (needs {', '.join(RAW_ARRAYS)})", column=key)
            a = arrays[key]
            if a.ndim != 1 or not np.issubdtype(a.dtype, np.number):
                raise SessionFormatError(
                    name, f"expected a 1-D numeric array, got shape {a.shape} dtype {a.dtype}", column=key
                )
            if not np.all(np.isfinite(a)):
                raise SessionFormatError(name, "contains NaN or inf", column=key, value=int(np.sum(~np.isfinite(a))))
        if arrays["grating_t"].size != arrays["grating_z"].size:
            raise SessionFormatError(
                name,
                f"grating_t has {arrays['grating_t'].size} samples but grating_z {arrays['grating_z'].size}",
                column="grating_z",
            )
        for key in ("grating_t", "pulse_t"):
            if np.any(np.diff(arrays[key]) < 0):
                raise SessionFormatError(name, "times must not decrease", column=key)
        raws[pid] = RawStreams(
            arrays["grating_t"].astype(float),
            arrays["grating_z"].astype(float),
            arrays["pulse_t"].astype(float),
            arrays.get("pulse_dir"),
            arrays.get("reference_t"),
        )
    return raws


def read_session(directory: str | os.PathLike) -> Session:
    """Read and validate a piga-session/1 directory; raise SessionFormatError on any defect."""
    d = Path(directory)
    if not d.is_dir():
        raise SessionFormatError(str(d), "not a directory")
    station, notes, meta = _read_station(d / "session.json")
    points = _read_points(d / "points.csv")
    raw = _read_raw(d / "raw", {p.point_id for p in points})
    return Session(station, points, notes=notes, raw=raw, meta=meta)


def _fmt(value) -> str:
    if value is None:
        return ""
    return repr(float(value)) if isinstance(value, float) else str(value)


def write_session(session: Session, directory: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write the session as piga-session/1 (exact float round trip); atomic rename into place."""
    d = Path(directory)
    if d.exists() and not overwrite:
        raise FileExistsError(f"{d} exists; pass overwrite=True to replace it")
    d.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{d.name}.", dir=d.parent))
    try:
        st = session.station
        doc = {"format": FORMAT, "station": {k: getattr(st, k) for k in STATION_KEYS}, "notes": session.notes}
        doc.update({k: v for k, v in session.meta.items() if k not in doc})
        doc.setdefault("raw_time_origin", "the window's opening edge (t = 0)")
        (tmp / "session.json").write_text(json.dumps(doc, indent=2))
        extras = sorted({k for p in session.points for k in p.extra})
        with (tmp / "points.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow([*COLUMNS, *extras])
            for p in session.points:
                w.writerow(
                    [
                        p.point_id,
                        p.sequence,
                        _fmt(p.start_s),
                        _fmt(p.position_deg),
                        _fmt(p.freq_hz),
                        p.kind,
                        p.pulses,
                        _fmt(p.Tm_s),
                        _fmt(p.t1_s),
                        _fmt(p.t2_s),
                        _fmt(p.Np),
                    ]
                    + [p.extra.get(k, "") for k in extras]
                )
        if session.raw:
            (tmp / "raw").mkdir()
            for pid, r in session.raw.items():
                arrays = {"grating_t": r.grating_t, "grating_z": r.grating_z, "pulse_t": r.pulse_t}
                if r.pulse_dir is not None:
                    arrays["pulse_dir"] = r.pulse_dir
                if r.reference_t is not None:
                    arrays["reference_t"] = r.reference_t
                np.savez_compressed(tmp / "raw" / f"{pid}.npz", **arrays)
        if d.exists():
            shutil.rmtree(d)
        tmp.rename(d)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return d
