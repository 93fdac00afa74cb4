"""Import and export of the `piga-session/1` interchange format (physics.md; docs/interchange.md).

A session directory holds session.json, points.csv, optionally raw/<point_id>.npz (physics.md) and, for the
sessions whose readings are not precession windows, one measurements/<kind>.csv per record type with the
arrays of its records in measurements/arrays/<sequence>.npz; session.json declares each table's typed,
unit-bearing columns (station/records.py) and carries the session's `provenance`. A directory with only
physics.md's fields still imports.

`read_session` reads and validates everything before returning, so a malformed session is refused whole:
every error names the file, the row, the column, the value and what is allowed. Files are read as data only
(station.safe_files, station.safe_arrays): a link or special file anywhere in the directory is refused, and every
array's declared size is checked against station.raw_limits before it is read. `content_hash` identifies
a session's measured content (independent of BOMs, line ends and column order), so that a store recognises
a re-import. Export writes to a temporary directory and renames it into place.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from station import constants
from station.errors import InputError
from station.provenance import ProvenanceError, check_provenance
from station.raw_limits import DEFAULT_LIMITS, Budget, RawInputError, RawLimits
from station.rawfile import RAW_SPECS, LazyRaw, RawWriter
from station.records import Field, RecordError, RecordType, declared
from station.safe_arrays import DTYPES_ALLOWED, NUMERIC_KINDS, Spec, load_npz, members, open_h5, read_group
from station.safe_files import check_tree, open_regular
from station.session import RAW_FIELDS, STATION_FIELDS, Measurement, PointRecord, RawStreams, Session, StationInfo

FORMAT = "piga-session/1"
COLUMNS = ("point_id", "sequence", "start_s", "position_deg", "freq_hz", "kind", "pulses", "Tm_s", "t1_s", "t2_s", "Np")
OPTIONAL_COLUMNS = ("dut", "pose", "temperature_c")
STATION_KEYS = tuple(f.name for f in STATION_FIELDS)
RAW_ARRAYS = ("grating_t", "grating_z", "pulse_t")
# The ranges of points.csv's numeric columns (t1_s, t2_s and Np are checked against the period T = 1/freq_hz):
# session time up to a year, the indexing head's travel (station.engine.planning: +-720 deg), the table's frequency
# (the station file allows freq_max_hz up to 100 Hz), signed counts and windows that fit the counter.
POINT_FIELDS: dict[str, Field] = {
    f.name: f
    for f in (
        Field("sequence", "int64", "", lo=0, hi=2**31 - 1),
        Field("start_s", "float64", "s", lo=0.0, hi=3.2e7),
        Field("position_deg", "float64", "deg", lo=-720.0, hi=720.0),
        Field("freq_hz", "float64", "Hz", lo=0.0, hi=100.0),
        Field("pulses", "int64", "", lo=-(2**53), hi=2**53),
        Field("Tm_s", "float64", "s", lo=0.0, hi=1e6, lo_open=True),
        Field("Np", "int64", "", lo=1, hi=2**31 - 1),
    )
}
# A vibration point's frequency: the table's lowest is 0.1 Hz (a station file may go lower, never to 0); below
# MIN_VIBRATION_HZ the period is not a time the counter could span.
MIN_VIBRATION_HZ = 1e-3
# t1 + Np T - Tm - t2 = 0 (physics.md) holds to the timing noise of the two reference-crossing stamps it
# involves, plus the frequency error eps_f of the table (its signature: eps_f Np T). session.json states them
# (physics.md's "timing": {"timer_resolution_s", "timing_sigma_s"}, and "frequency_stability", the largest
# |eps_f|); unstated, the counter's 50 ns ticks, 100 ns jitter and |eps_f| <= 1e-4 (5x seed 000 Table 6's
# worst sigma_f / f, 2e-5): Np one period off is then refused on every window of up to 5000 periods.
TIMING_DEFAULTS = {"timer_resolution_s": constants.TIMER_TICK_S, "timing_sigma_s": 1e-7,
                   "frequency_stability": 1e-4}  # fmt: skip
TIMING_MAX = {"timer_resolution_s": 1e-3, "timing_sigma_s": 1e-3,
              "frequency_stability": constants.FREQ_STABILITY_MAX}  # fmt: skip
TIMING_SIGMAS = 6.0  # the stamps' noise allowed in the identity: 6 sd
ROUNDING_REL = 1e-12  # the identity's sums of doubles round to ~1e-16 relative; a crossing this close to T is at T
MAX_JSON_BYTES = 64 << 20  # session.json: declarations, provenance, notes; never arrays
MEASUREMENTS_DIR = "measurements"
RAW_FILE = "raw.h5"  # the points' raw streams, one HDF5 group per point_id (physics.md's raw/*.npz is read too)
_SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,127}")  # a point_id, a record kind: a file name
SAFE_NAME_ALLOWED = "1-128 letters, digits, . _ + -, starting with a letter or digit"
_RESERVED = ("sequence", "key", "arrays_file")  # the columns of a measurements table before its fields
OWN_KEYS = ("format", "station", "notes", "provenance", "measurements", "results")  # the rest of session.json: meta


STORE_UID = re.compile(r"^[0-9A-Za-z-]{1,64}$")  # session.json store_uid: the uid an import keeps


class SessionFormatError(InputError):
    """A session directory that does not follow piga-session/1."""

    def __init__(
        self,
        file: str,
        message: str,
        row: int | None = None,
        column: str | None = None,
        value=None,
        dataset: str | None = None,
    ):
        where = file
        if row is not None:
            where += f" row {row}"
        if column is not None:
            where += f", column {column!r}"
        if dataset is not None:
            where += f", dataset {dataset!r}"
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
    return int(text)


def _ranged(text: str, file: str, row: int, column: str) -> float | int:
    """A points.csv cell in its declared type and range (POINT_FIELDS)."""
    f = POINT_FIELDS[column]
    value = (_integer if f.dtype == "int64" else _number)(text, file, row, column)
    if not f.in_range(value):
        raise SessionFormatError(file, f"must be {f.allowed()}", row, column, text)
    return value


class NonFiniteError(Exception):
    """NaN, Infinity or -Infinity in a JSON text (Python's json reads them; JSON has no such numbers)."""


def _no_constant(text: str) -> Any:
    raise NonFiniteError(text)


def _finite_float(text: str) -> float:
    value = float(text)  # 1e999 reads as inf
    if not math.isfinite(value):
        raise NonFiniteError(text)
    return value


def _read_json(path: Path, name: str) -> Any:
    if not path.is_file():
        raise SessionFormatError(name, f"missing: a {FORMAT} directory needs {path}")
    with open_regular(path, name) as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > MAX_JSON_BYTES:
            raise SessionFormatError(name, f"{size} bytes; at most {MAX_JSON_BYTES >> 20} MiB")
        text = fh.read(size)
    try:
        return json.loads(text.decode("utf-8-sig"), parse_constant=_no_constant, parse_float=_finite_float)
    except NonFiniteError as exc:
        raise SessionFormatError(name, "a number out of range: JSON numbers are finite doubles (no NaN, Infinity "
                                 "or 1e999)", value=exc.args[0]) from None  # fmt: skip
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SessionFormatError(name, f"not valid JSON ({exc})") from None
    except RecursionError:
        raise SessionFormatError(name, "not valid JSON (nested too deeply)") from None


@dataclass(frozen=True)
class Timing:
    """What session.json states of its timing noise (TIMING_DEFAULTS where it does not)."""

    timer_resolution_s: float
    timing_sigma_s: float
    frequency_stability: float

    @classmethod
    def from_meta(cls, meta: Mapping[str, Any], file: str) -> Timing:
        stated = meta.get("timing", {})
        if not isinstance(stated, dict):
            raise SessionFormatError(file, "'timing' must be an object", column="timing", value=stated)
        values = dict(TIMING_DEFAULTS)
        for key, v in stated.items():
            if key not in TIMING_DEFAULTS:
                continue  # physics.md allows extra keys
            if v is None:
                continue
            top = TIMING_MAX[key]
            if isinstance(v, bool) or not isinstance(v, int | float) or not 0 <= v <= top:
                raise SessionFormatError(file, f"must be a number in [0, {top:g}]", column=f"timing.{key}", value=v)
            values[key] = float(v)
        return cls(**values)

    def tolerance_s(self, periods_s: float) -> float:
        """|t1 + Np T - Tm - t2| allowed over a span of Np T = periods_s: the two crossing stamps' noise and
        the frequency error."""
        stamp_sd = math.sqrt(self.timing_sigma_s**2 + self.timer_resolution_s**2 / 12.0)
        return TIMING_SIGMAS * math.sqrt(2.0) * stamp_sd + (self.frequency_stability + ROUNDING_REL) * periods_s


def _read_station(path: Path) -> tuple[StationInfo, str, dict, dict, list[dict]]:
    name = "session.json"
    data = _read_json(path, name)
    if not isinstance(data, dict):
        raise SessionFormatError(name, "expected a JSON object at the top level")
    if data.get("format") != FORMAT:
        raise SessionFormatError(name, f"'format' must be {FORMAT!r}", column="format", value=data.get("format"))
    st = data.get("station")
    if not isinstance(st, dict):
        raise SessionFormatError(name, "'station' must be an object with " + ", ".join(STATION_KEYS), column="station")
    values = {}
    for f in STATION_FIELDS:
        column = f"station.{f.name}"
        if f.name not in st:
            raise SessionFormatError(name, f"missing station key (allowed: {f.allowed()})", column=column)
        try:
            values[f.name] = f.coerce(st[f.name], name)
        except RecordError:
            raise SessionFormatError(name, f"must be {f.allowed()}", column=column, value=st[f.name]) from None
    notes = data.get("notes", "")
    try:
        provenance = check_provenance(data["provenance"], name) if "provenance" in data else {}
    except ProvenanceError as exc:
        raise SessionFormatError(name, str(exc).removeprefix(f"{name}: "), column="provenance") from None
    tables = data.get("measurements", [])
    if not isinstance(tables, list):
        raise SessionFormatError(
            name, "'measurements' must be a list of record type declarations", column="measurements"
        )
    meta = {k: v for k, v in data.items() if k not in OWN_KEYS}
    if "store_uid" in meta and not (isinstance(meta["store_uid"], str) and STORE_UID.match(meta["store_uid"])):
        raise SessionFormatError(name, "must be the session's uid in the store it came from: 1-64 letters, digits "
                                 "and '-'", column="store_uid", value=meta["store_uid"])  # fmt: skip
    meta["results"] = _check_results(data.get("results", []), provenance.get("created_utc"), name)
    meta["declares_measurements"] = "measurements" in data
    return StationInfo(**values), notes if isinstance(notes, str) else json.dumps(notes), meta, provenance, tables


RESULT_KEYS = ("method", "created_utc", "result")
CLOCK_SKEW = timedelta(days=1)  # another station's clock may be ahead of ours


def _utc(text: Any, file: str, column: str) -> datetime:
    """An ISO 8601 time with its UTC offset, as the station writes them."""
    try:
        t = datetime.fromisoformat(text) if isinstance(text, str) else None
    except ValueError:
        t = None
    if t is None or t.tzinfo is None:
        raise SessionFormatError(file, "must be an ISO 8601 time with its UTC offset (2026-12-01T19:54:18.120+00:00)",
                                 column=column, value=text)  # fmt: skip
    return t


def _check_results(results: Any, recorded_utc: Any, file: str) -> list[dict]:
    """The analyses' results as the store keeps its own (Store.add_result): a method name, the time it was computed
    and a JSON object of finite numbers (the import's JSON reader refuses NaN and Infinity); computed after the
    session was recorded (provenance.created_utc, when stated) and not in the future."""
    if not isinstance(results, list):
        raise SessionFormatError(file, "'results' must be a list of {method, created_utc, result} objects",
                                 column="results")  # fmt: skip
    recorded = _utc(recorded_utc, file, "provenance.created_utc") if results and recorded_utc is not None else None
    latest = datetime.now(UTC) + CLOCK_SKEW
    for i, r in enumerate(results):
        where = f"results[{i}]"
        if not isinstance(r, dict) or sorted(r) != sorted(RESULT_KEYS):
            raise SessionFormatError(file, "must be an object with exactly the keys method, created_utc, result",
                                     column=where, value=r if not isinstance(r, dict) else sorted(r))  # fmt: skip
        if not isinstance(r["method"], str) or not _SAFE_NAME.fullmatch(r["method"]):
            raise SessionFormatError(file, f"a method name: {SAFE_NAME_ALLOWED}", column=f"{where}.method",
                                     value=r["method"])  # fmt: skip
        when = _utc(r["created_utc"], file, f"{where}.created_utc")
        if when > latest or (recorded is not None and when < recorded):
            raise SessionFormatError(
                file,
                f"a result is computed after the session was recorded ({recorded_utc}) and not in the future",
                column=f"{where}.created_utc",
                value=r["created_utc"],
            )
        if not isinstance(r["result"], dict):
            raise SessionFormatError(
                file, "must be a JSON object", column=f"{where}.result", value=type(r["result"]).__name__
            )
    return results


def _parse_row(row: dict[str, str], file: str, n: int, timing: Timing) -> PointRecord:
    point_id = row["point_id"].strip()
    if not _SAFE_NAME.fullmatch(point_id):
        raise SessionFormatError(file, f"point_id must be {SAFE_NAME_ALLOWED}", n, "point_id", row["point_id"])
    kind = row["kind"].strip()
    if kind not in ("static", "vibration"):
        raise SessionFormatError(file, "kind must be 'static' or 'vibration'", n, "kind", row["kind"])
    sequence = int(_ranged(row["sequence"], file, n, "sequence"))
    start = _ranged(row["start_s"], file, n, "start_s")
    position = _ranged(row["position_deg"], file, n, "position_deg")
    freq = _ranged(row["freq_hz"], file, n, "freq_hz")
    pulses = int(_ranged(row["pulses"], file, n, "pulses"))
    if pulses == 0:
        raise SessionFormatError(file, "pulses must be a non-zero signed count", n, "pulses", row["pulses"])
    tm = _ranged(row["Tm_s"], file, n, "Tm_s")
    extra = {k: row[k] for k in row if k not in COLUMNS and row[k]}  # an empty cell: the point has no such value
    if kind == "static":
        if freq != 0:
            raise SessionFormatError(file, "a static point must have freq_hz = 0", n, "freq_hz", row["freq_hz"])
        for col in ("t1_s", "t2_s", "Np"):
            if row[col].strip():
                raise SessionFormatError(file, "must be empty for a static point", n, col, row[col])
        return PointRecord(point_id, sequence, start, position, 0.0, "static", pulses, tm, extra=extra)
    if not freq >= MIN_VIBRATION_HZ:
        raise SessionFormatError(file, f"a vibration point needs freq_hz in [{MIN_VIBRATION_HZ:g}, 100] Hz", n,
                                 "freq_hz", row["freq_hz"])  # fmt: skip
    t1 = _number(row["t1_s"], file, n, "t1_s")
    t2 = _number(row["t2_s"], file, n, "t2_s")
    n_periods = int(_ranged(row["Np"], file, n, "Np"))
    _check_periods(tm, t1, t2, n_periods, freq, timing, lambda column, message: SessionFormatError(
        file, message, n, column, row[column]))  # fmt: skip
    return PointRecord(point_id, sequence, start, position, freq, "vibration", pulses, tm, t1, t2, n_periods, extra)


def _check_periods(
    tm: float, t1: float, t2: float, n_periods: int, freq: float, timing: Timing,
    error: Callable[[str, str], SessionFormatError],
) -> None:  # fmt: skip
    """physics.md: t1 in (0, T], t2 in [0, T) of the period the table turned at (Tm - t1 + t2) / Np, and
    t1 + Np T - Tm - t2 = 0 with T = 1 / freq_hz within the stated timing noise and frequency error."""
    period = 1.0 / freq
    longest = period * (1.0 + timing.frequency_stability)  # the period of a table turning slow by the most allowed
    if not 0 < t1 <= longest:
        raise error("t1_s", f"t1_s must lie in (0, T], T = {period:.9g} s")
    if not 0 <= t2 < longest:
        raise error("t2_s", f"t2_s must lie in [0, T), T = {period:.9g} s")
    if not t1 < tm:
        raise error("t1_s", f"t1_s must be before Tm_s = {tm!r}")
    spanned = tm - t1 + t2
    residual = n_periods * period - spanned
    allowed = timing.tolerance_s(n_periods * period)
    if not abs(residual) <= allowed:
        raise error("Np", f"t1 + Np T - Tm - t2 = {residual:.6g} s with T = 1/freq_hz = {period:.9g} s; allowed "
                    f"+-{allowed:.3g} s (timing noise and a frequency error up to {timing.frequency_stability:g}, "
                    "session.json 'timing'): Np is not the whole periods from t1 to the closing crossing")  # fmt: skip
    turned = spanned / n_periods  # the period the table turned at
    if not t1 <= turned:
        raise error("t1_s", f"t1_s must lie in (0, T], T = (Tm - t1 + t2) / Np = {turned:.9g} s")
    if not t2 < turned * (1.0 - ROUNDING_REL):
        raise error("t2_s", f"t2_s must lie in [0, T), T = (Tm - t1 + t2) / Np = {turned:.9g} s")


def _csv_rows(path: Path, name: str, required: tuple[str, ...]) -> Iterator[tuple[int, dict[str, str]]]:
    """The rows of a CSV file (UTF-8, with or without a BOM, LF or CRLF) as (row number, cells by column);
    a header with a column twice, or without a required one, is refused."""
    if not path.is_file():
        raise SessionFormatError(name, f"missing: {path}")
    try:
        with io.TextIOWrapper(open_regular(path, name), encoding="utf-8-sig", newline="") as fh:
            reader = csv.reader(fh)
            header = next(reader, [])
            header = [h.strip() for h in header]
            for i, h in enumerate(header):
                if header.index(h) != i:
                    raise SessionFormatError(name, f"column named twice (columns {header.index(h) + 1} and {i + 1})",
                                             1, h)  # fmt: skip
            missing = [c for c in required if c not in header]
            if missing:
                raise SessionFormatError(
                    name, f"missing column(s) {', '.join(missing)}; header must include {','.join(required)}", 1
                )
            for n, cells in enumerate(reader, start=2):
                if not cells:
                    continue
                if len(cells) != len(header):
                    raise SessionFormatError(name, f"expected {len(header)} fields, found {len(cells)}", n)
                yield n, dict(zip(header, cells, strict=True))
    except UnicodeDecodeError as exc:
        raise SessionFormatError(name, f"not UTF-8 text ({exc})") from None
    except csv.Error as exc:
        raise SessionFormatError(name, f"malformed CSV ({exc})") from None


def _read_points(path: Path, timing: Timing) -> list[PointRecord]:
    name = "points.csv"
    if not path.is_file():
        raise SessionFormatError(name, f"missing: a {FORMAT} directory needs {path}")
    points: list[PointRecord] = []
    ids: dict[str, int] = {}
    sequences: dict[int, int] = {}
    for n, row in _csv_rows(path, name, COLUMNS):
        p = _parse_row(row, name, n, timing)
        if p.point_id in ids:
            raise SessionFormatError(name, f"duplicate point_id (first on row {ids[p.point_id]})", n, "point_id",
                                     p.point_id)  # fmt: skip
        if p.sequence in sequences:
            raise SessionFormatError(name, f"duplicate sequence (first on row {sequences[p.sequence]})", n,
                                     "sequence", row["sequence"])  # fmt: skip
        ids[p.point_id], sequences[p.sequence] = n, n
        points.append(p)
    return points


def _check_raw(arrays: Mapping[str, np.ndarray], name: str, kind: str) -> None:
    """physics.md's raw record: grating_t, grating_z, pulse_t (optional pulse_dir, reference_t); 1-D, real
    numeric, finite, grating_t and grating_z of one length, pulse_dir one +1 or -1 per pulse edge, times
    non-decreasing; pulse_t not empty (the point counted pulses), the grating not empty for a vibration point
    (a station records none at rest)."""
    for key in RAW_ARRAYS:
        if key not in arrays:
            raise SessionFormatError(name, f"missing array (needs {', '.join(RAW_ARRAYS)})", column=key)
    for key, a in arrays.items():
        if key not in RAW_FIELDS:
            raise SessionFormatError(name, f"unknown array (allowed: {', '.join(RAW_FIELDS)})", column=key)
        if a.ndim != 1 or a.dtype.kind not in NUMERIC_KINDS:
            raise SessionFormatError(
                name, f"expected a 1-D array of {DTYPES_ALLOWED}, got shape {a.shape} dtype {a.dtype}", column=key
            )
        if a.size == 0 and (key == "pulse_t" or (kind == "vibration" and key in ("grating_t", "grating_z"))):
            raise SessionFormatError(name, f"empty: a {kind} point's record holds its pulse edges"
                                     + (" and the table's motion" if kind == "vibration" else ""),
                                     column=key, value=f"shape {a.shape}")  # fmt: skip
        if not np.all(np.isfinite(a)):
            raise SessionFormatError(name, "contains NaN or inf", column=key, value=int(np.sum(~np.isfinite(a))))
    if arrays["grating_t"].size != arrays["grating_z"].size:
        raise SessionFormatError(
            name,
            f"grating_t has {arrays['grating_t'].size} samples but grating_z {arrays['grating_z'].size}",
            column="grating_z",
        )
    direction = arrays.get("pulse_dir")
    if direction is not None:
        if direction.size != arrays["pulse_t"].size:
            raise SessionFormatError(name, f"one direction per pulse edge: pulse_t has {arrays['pulse_t'].size}",
                                     column="pulse_dir", value=f"{direction.size} values")  # fmt: skip
        if not np.all(np.abs(direction) == 1):
            raise SessionFormatError(name, "each value must be +1 or -1", column="pulse_dir")
    for key in ("grating_t", "pulse_t", "reference_t"):
        if key in arrays and np.any(np.diff(arrays[key]) < 0):
            raise SessionFormatError(name, "times must not decrease", column=key)


def _read_raw(d: Path, kinds: dict[str, str], budget: Budget) -> Mapping[str, RawStreams]:
    """raw/<point_id>.npz (physics.md), read whole; or raw.h5 (one group per point), checked point by point and
    then read lazily (a session's raw streams may not fit in memory)."""
    raw_dir, h5 = d / "raw", d / RAW_FILE
    npz = sorted(raw_dir.glob("*.npz")) if raw_dir.is_dir() else []
    if npz and h5.exists():
        raise SessionFormatError(RAW_FILE, "a session has raw/*.npz or raw.h5, not both")
    if h5.exists():
        digests: dict[str, bytes] = {}
        with open_h5(h5, RAW_FILE) as f:
            for pid, group in members(f, RAW_FILE):
                name = f"{RAW_FILE}:/{pid}"
                if pid not in kinds:
                    raise SessionFormatError(name, "no point with this point_id in points.csv", value=pid)
                if not isinstance(group, h5py.Group):
                    raise SessionFormatError(name, "expected a group of datasets (one per array)")
                arrays = read_group(group, RAW_FILE, RAW_SPECS, budget)
                _check_raw(arrays, name, kinds[pid])
                digests[pid] = raw_digest(RawStreams.from_arrays(arrays))
                del arrays  # one point's arrays in memory at a time
        lazy = LazyRaw.of_file(h5, list(digests), budget.limits)
        lazy.digests = digests
        return lazy
    raws: dict[str, RawStreams] = {}
    for path in npz:
        name = f"raw/{path.name}"
        pid = path.stem
        if pid not in kinds:
            raise SessionFormatError(name, "no point with this point_id in points.csv", value=pid)
        arrays = load_npz(path, name, RAW_SPECS, budget)
        _check_raw(arrays, name, kinds[pid])
        raws[pid] = RawStreams(
            arrays["grating_t"].astype(float),
            arrays["grating_z"].astype(float),
            arrays["pulse_t"].astype(float),
            arrays.get("pulse_dir"),
            arrays.get("reference_t"),
        )
    return raws


def _cell(f: Field, text: str, file: str, n: int) -> Any:
    """One cell of a measurements table in its declared type: lists as JSON, an empty cell as null."""
    if text == "" and (f.nullable or f.dtype != "str" or f.ndim):
        value: Any = None
    elif f.ndim:
        try:
            value = json.loads(text)
        except (json.JSONDecodeError, RecursionError):
            raise SessionFormatError(file, f"expected a JSON list ({f.allowed()})", n, f.name, text[:80]) from None
    elif f.dtype == "float64":
        value = _number(text, file, n, f.name)
    elif f.dtype == "int64":
        value = _integer(text, file, n, f.name)
    elif f.dtype == "bool":
        if text not in ("true", "false"):
            raise SessionFormatError(file, "expected true or false", n, f.name, text)
        value = text == "true"
    else:
        value = text
    try:
        return f.coerce(value, file)
    except RecordError:
        raise SessionFormatError(file, f"must be {f.allowed()}", n, f.name, text[:80]) from None


def _read_measurements(d: Path, tables: list[Any], budget: Budget) -> tuple[list[Measurement], list[RecordType]]:
    name = "session.json"
    types: list[RecordType] = []
    found: list[tuple[int, Measurement]] = []
    keys: dict[str, str] = {}
    sequences: dict[int, str] = {}
    for i, doc in enumerate(tables):
        try:
            rt = RecordType.from_json(doc, f"measurements[{i}]")
        except (RecordError, TypeError) as exc:
            raise SessionFormatError(
                name, f"bad record type declaration ({exc})", column=f"measurements[{i}]"
            ) from None
        if not _SAFE_NAME.fullmatch(rt.kind) or rt.kind in {t.kind for t in types}:
            raise SessionFormatError(name, "kind must be a unique name of letters, digits, . _ + -",
                                     column=f"measurements[{i}].kind", value=rt.kind)  # fmt: skip
        clash = [f.name for f in rt.fields if f.name in _RESERVED]
        if clash:
            raise SessionFormatError(name, f"field names {', '.join(_RESERVED)} are the table's own",
                                     column=f"measurements[{i}].fields", value=clash)  # fmt: skip
        types.append(rt)
        file = f"{MEASUREMENTS_DIR}/{rt.kind}.csv"
        required = ("sequence", "key", *(f.name for f in rt.fields if not f.nullable))
        for n, row in _csv_rows(d / file, file, required):
            unknown = sorted(set(row) - {*_RESERVED, *(f.name for f in rt.fields)})
            if unknown:
                raise SessionFormatError(file, f"column not declared in session.json for kind {rt.kind!r}", 1,
                                         unknown[0])  # fmt: skip
            seq = _integer(row["sequence"], file, n, "sequence")
            key = row["key"]
            if not key:
                raise SessionFormatError(file, "key must not be empty", n, "key", key)
            if key in keys:
                raise SessionFormatError(file, f"duplicate key (first in {keys[key]})", n, "key", key)
            if seq in sequences:
                raise SessionFormatError(file, f"duplicate sequence (first in {sequences[seq]})", n, "sequence", seq)
            keys[key] = sequences[seq] = f"{file} row {n}"
            values = {f.name: _cell(f, row[f.name], file, n) for f in rt.fields if f.name in row}
            values = {k: v for k, v in values.items() if v is not None or rt.field(k).nullable}
            arrays = _measurement_arrays(d, rt, row.get("arrays_file", ""), file, n, budget)
            found.append((seq, Measurement(key, rt.kind, values, arrays)))
    return [m for _, m in sorted(found, key=lambda sm: sm[0])], types


def _array_specs(rt: RecordType) -> dict[str, Spec]:
    """What a record type's arrays may be in a file: declared dimensions, numeric (a 'str' array: unicode)."""
    return {a.name: (max(a.ndim, 1), "U" if a.dtype == "str" else NUMERIC_KINDS) for a in rt.arrays}


def _measurement_arrays(d: Path, rt: RecordType, ref: str, file: str, n: int, budget: Budget) -> dict[str, np.ndarray]:
    if not ref:
        return {}
    rel = Path(ref)
    if rel.is_absolute() or ".." in rel.parts or rel.parts[:2] != (MEASUREMENTS_DIR, "arrays"):
        raise SessionFormatError(file, f"must name a file in {MEASUREMENTS_DIR}/arrays/", n, "arrays_file", ref)
    arrays = load_npz(d / rel, ref, _array_specs(rt), budget)
    try:
        return rt.check_arrays(arrays, ref)
    except RecordError as exc:
        raise SessionFormatError(ref, f"must be {exc.allowed}", column=exc.name, value=exc.value) from None


def read_session(directory: str | os.PathLike, limits: RawLimits = DEFAULT_LIMITS) -> Session:
    """Read and validate a piga-session/1 directory; raise SessionFormatError on any defect. Its arrays together
    and each one are held to `limits` before they are read."""
    d = Path(directory)
    if not d.is_dir():
        raise SessionFormatError(str(d), "not a directory")
    budget = Budget(limits)
    try:
        check_tree(d)
        station, notes, meta, provenance, tables = _read_station(d / "session.json")
        points = _read_points(d / "points.csv", Timing.from_meta(meta, "session.json"))
        raw = _read_raw(d, {p.point_id: p.kind for p in points}, budget)
        measurements, types = _read_measurements(d, tables, budget)
    except RawInputError as exc:
        raise SessionFormatError(exc.file, exc.reason, dataset=exc.dataset) from None
    results = meta.pop("results")
    if not points and not measurements and not meta.pop("declares_measurements"):
        raise SessionFormatError("points.csv", "no points (and no 'measurements' in session.json)")
    meta.pop("declares_measurements", None)
    return Session(station, points, notes=notes, raw=raw, meta=meta, measurements=measurements,
                   provenance=provenance, record_types=types, results=results)  # fmt: skip


def _digest_array(h: Any, name: str, a: np.ndarray | None) -> None:
    if a is None:
        return
    a = np.ascontiguousarray(a)
    h.update(f"{name}:{a.dtype.str}:{a.shape}".encode())
    h.update(a.tobytes())


def content_hash(session: Session) -> str:
    """SHA-256 of what the session measured: station, points, measurements and every array (not notes, not
    the provenance, not how the files were laid out)."""
    h = hashlib.sha256()
    doc = {
        "station": asdict(session.station),
        "points": [asdict(p) for p in session.points],
        "measurements": [[m.key, m.kind, m.values] for m in session.measurements],
    }
    h.update(json.dumps(doc, sort_keys=True, allow_nan=False).encode())
    for m in session.measurements:
        for name in sorted(m.arrays):
            _digest_array(h, f"{m.key}/{name}", np.asarray(m.arrays[name]))
    known = getattr(session.raw, "digests", {})  # raw.h5's points were digested as the import checked them
    for pid in sorted(session.raw):
        h.update(pid.encode())
        h.update(known.get(pid) or raw_digest(session.raw[pid]))
    return h.hexdigest()


def raw_digest(raw: RawStreams) -> bytes:
    """SHA-256 of one point's raw arrays (dtype, shape and bytes of each)."""
    h = hashlib.sha256()
    for name in RAW_FIELDS:
        _digest_array(h, name, getattr(raw, name))
    return h.digest()


def _fmt(value) -> str:
    if value is None:
        return ""
    return repr(float(value)) if isinstance(value, float) else str(value)


def _fmt_cell(f: Field, value: Any) -> str:
    if value is None:
        return ""
    if f.ndim:
        return json.dumps(value, allow_nan=False)
    if f.dtype == "bool":
        return "true" if value else "false"
    return _fmt(value)


def _session_types(session: Session) -> list[RecordType]:
    """The declaration of every kind the session's measurements have (the session's own, else this process's)."""
    own = {rt.kind: rt for rt in session.record_types}
    out = []
    for kind in dict.fromkeys(m.kind for m in session.measurements):
        rt = own.get(kind) or declared(kind)
        if rt is None:
            raise SessionFormatError(f"{MEASUREMENTS_DIR}/{kind}.csv", "no record type declared for this kind",
                                     value=kind)  # fmt: skip
        out.append(rt)
    return out


def _write_measurements(session: Session, tmp: Path) -> list[dict]:
    types = _session_types(session)
    if not types:
        return []
    (tmp / MEASUREMENTS_DIR / "arrays").mkdir(parents=True)
    for rt in types:
        with (tmp / MEASUREMENTS_DIR / f"{rt.kind}.csv").open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["sequence", "key", *(f.name for f in rt.fields), *(["arrays_file"] if rt.arrays else [])])
            for seq, m in enumerate(session.measurements):
                if m.kind != rt.kind:
                    continue
                values = rt.check_values(m.values, f"measurement {m.key!r}")
                row = [str(seq), m.key, *(_fmt_cell(f, values.get(f.name)) for f in rt.fields)]
                if rt.arrays:
                    ref = ""
                    if m.arrays:
                        ref = f"{MEASUREMENTS_DIR}/arrays/{seq}.npz"
                        np.savez_compressed(
                            tmp / ref, allow_pickle=False, **rt.check_arrays(m.arrays, f"measurement {m.key!r}")
                        )
                    row.append(ref)
                w.writerow(row)
    return [rt.to_json() | {"file": f"{MEASUREMENTS_DIR}/{rt.kind}.csv"} for rt in types]


class SessionWriter:
    """A piga-session/1 directory written as the session goes: points one by one, their raw streams straight into
    raw.h5 (flushed per point: memory holds one point's arrays, not the session's), then `finish` writes the
    tables and session.json and renames the directory into place; nothing is in place until then."""

    def __init__(self, directory: str | os.PathLike, *, overwrite: bool = False) -> None:
        self.directory = Path(directory)
        if self.directory.exists() and not overwrite:
            raise FileExistsError(f"{self.directory} exists; pass overwrite=True to replace it")
        self.directory.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = Path(tempfile.mkdtemp(prefix=f".{self.directory.name}.", dir=self.directory.parent))
        self._points: list[PointRecord] = []
        self._raw: RawWriter | None = None

    def add_point(self, point: PointRecord, raw: RawStreams | None = None) -> None:
        self._points.append(point)
        if raw is not None:
            if self._raw is None:
                self._raw = RawWriter(self._tmp / RAW_FILE)
            self._raw.add(point.point_id, raw)

    def finish(self, session: Session) -> Path:
        """Everything but the points' raw streams from `session` (its points, if none were added); into place."""
        try:
            if self._raw is not None:
                self._raw.close()
                self._raw = None
            points = self._points or session.points
            st = session.station
            doc: dict[str, Any] = {"format": FORMAT, "station": {k: getattr(st, k) for k in STATION_KEYS},
                                   "notes": session.notes}  # fmt: skip
            if session.provenance:
                doc["provenance"] = session.provenance
            doc.update({k: v for k, v in session.meta.items() if k not in OWN_KEYS})
            doc["timing"] = _stated_timing(doc.get("timing"), points)
            doc.setdefault("raw_time_origin", "the window's opening edge (t = 0)")
            doc["measurements"] = _write_measurements(session, self._tmp)
            if session.results:
                doc["results"] = session.results
            (self._tmp / "session.json").write_text(json.dumps(doc, indent=2), encoding="utf-8")
            _write_points(points, self._tmp / "points.csv")
            if self.directory.exists():
                shutil.rmtree(self.directory)
            self._tmp.rename(self.directory)
        except BaseException:
            self.abort()
            raise
        return self.directory

    def abort(self) -> None:
        if self._raw is not None:
            self._raw.close()
            self._raw = None
        shutil.rmtree(self._tmp, ignore_errors=True)


def frequency_error(points: list[PointRecord]) -> float:
    """The largest |eps_f| the vibration points show (0 without any): the frequency error of each one's period
    identity, |t1 + Np T - Tm - t2| / (Np T), and how far t1 or t2 reach past T = 1 / freq_hz (_check_periods
    allows both up to T (1 + frequency_stability))."""
    worst = 0.0
    for p in points:
        if p.kind != "vibration" or not p.Np or not p.freq_hz or p.t1_s is None or p.t2_s is None:
            continue
        period = 1.0 / p.freq_hz
        spanned = p.Tm_s - p.t1_s + p.t2_s
        worst = max(worst, abs(p.Np * period - spanned) / (p.Np * period), p.t1_s / period - 1.0, p.t2_s / period - 1.0)
    return worst


def _stated_timing(stated: Any, points: list[PointRecord]) -> dict:
    """session.json's 'timing' on export: what the session states, its frequency_stability at least the largest
    |eps_f| its points show (frequency_error, rounded up to two digits) and at least the default: whatever the
    station stored (its engine allows |eps_f| up to station.engine.timing.FREQ_TOLERANCE_REL, 5e-4, where an import
    assumes 1e-4 unless told) imports again. Above FREQ_STABILITY_MAX it is stated as that most, and the import
    refuses the point that needs more, naming it."""
    timing = dict(stated) if isinstance(stated, dict) else {}
    shown = frequency_error(points)
    if shown > 0:
        digits = 10.0 ** (math.floor(math.log10(shown)) - 1)
        shown = math.ceil(shown * (1 + 1e-9) / digits) * digits  # up, never down, to two significant digits
    current = timing.get("frequency_stability")
    base = current if isinstance(current, int | float) and not isinstance(current, bool) else 0.0
    stability = max(base, shown, TIMING_DEFAULTS["frequency_stability"])
    timing["frequency_stability"] = min(stability, TIMING_MAX["frequency_stability"])
    return timing


def _write_points(points: list[PointRecord], path: Path) -> None:
    extras = sorted({k for p in points for k in p.extra})
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow([*COLUMNS, *extras])
        for p in points:
            w.writerow(
                [p.point_id, p.sequence, _fmt(p.start_s), _fmt(p.position_deg), _fmt(p.freq_hz), p.kind, p.pulses,
                 _fmt(p.Tm_s), _fmt(p.t1_s), _fmt(p.t2_s), _fmt(p.Np)]
                + [p.extra.get(k, "") for k in extras]
            )  # fmt: skip


def write_session(session: Session, directory: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write the session as piga-session/1 (exact float round trip), raw streams point by point into raw.h5;
    atomic rename into place."""
    writer = SessionWriter(directory, overwrite=overwrite)
    try:
        for p in session.points:
            writer.add_point(p, session.raw.get(p.point_id))
    except BaseException:
        writer.abort()
        raise
    return writer.finish(session)
