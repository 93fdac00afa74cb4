"""Issue 30 (7): a bounded fuzz campaign over import directories and procedure files (hypothesis, derandomized).

A case is a valid input with one mutation drawn from IMPORT_MUTATIONS (a piga-session/1 directory: points.csv,
session.json, record declarations, results, raw.h5, raw/*.npz, measurement tables and arrays, stray files) or
PROCEDURE_MUTATIONS (a shipped procedure TOML file), read as `station import` and `station run FILE` read them.
Asserted for every case:
- no traceback: nothing but the InputError family (and the store's own refusal, StoreError) is raised;
- no accepted invalid input: what is accepted passes `session_defects` / `params_defects`, a restatement of
  docs/interchange.md and of each procedure's declared parameters written apart from the code under test, and a
  mutation that makes the input invalid by construction (`True` from the mutation) is refused;
- no store change on refusal: the store's sessions and files are what they were before the case.

bench/fuzz_imports.py runs the same cases for longer and counts them (BENCHMARKS.md).
"""

from __future__ import annotations

import csv
import json
import math
import os
import random
import re
import shutil
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from station.engine.registry import load_library, load_procedure_file, procedure_file_serial
from station.errors import InputError
from station.interchange import content_hash, read_session, write_session
from station.provenance import make_provenance
from station.records import Field, RecordType
from station.session import Measurement, Session
from station.store import SessionStore, StoreError
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session

ROOT = Path(__file__).resolve().parents[1]
PROCEDURE_FILES = sorted((ROOT / "config" / "procedures").glob("*.toml"))
CLEAN_REFUSALS = (InputError, StoreError)

# --- the valid inputs the mutations start from --------------------------------------------------------------

PROBE = RecordType(
    "probe",
    (Field("level_v", "float64", "V", lo=0.0, hi=10.0), Field("n", "int64", lo=1, hi=9),
     Field("tags", "str", ndim=1, nullable=True), Field("ok", "bool")),
    arrays=(Field("trace_v", "float64", "V", lo=-5.0, hi=5.0),),
)  # fmt: skip
RESULT = {"method": "integral", "created_utc": "2026-12-01T20:00:00.000+00:00", "result": {"kz": 0.56, "u": [1e-7]}}


def make_bases(root: Path) -> dict[str, Path]:
    """Three valid directories: raw streams in raw.h5, the same as raw/*.npz, and typed measurement records."""
    s = simulate_session(multiposition_plan([0.0], [10.0], window_s=1.0), TwinConfig(), seed=3, raw=True)
    prov = make_provenance(station_id="fuzz", simulated=True, seed=3, created_utc="2026-12-01T19:54:18.120+00:00")
    s = Session(s.station, s.points, raw=s.raw, provenance=prov, results=[RESULT],
                meta={"timing": {"timer_resolution_s": 5e-8, "timing_sigma_s": 1e-7}})  # fmt: skip
    bases = {"h5": write_session(s, root / "h5")}
    npz = root / "npz"
    shutil.copytree(bases["h5"], npz)
    (npz / "raw.h5").unlink()
    (npz / "raw").mkdir()
    for pid, r in s.raw.items():
        arrays = {k: getattr(r, k) for k in ("grating_t", "grating_z", "pulse_t", "pulse_dir", "reference_t")}
        np.savez_compressed(npz / "raw" / f"{pid}.npz", **{k: v for k, v in arrays.items() if v is not None})
    bases["npz"] = npz
    ms = [Measurement("m1", "probe", {"level_v": 1.5, "n": 3, "tags": ["a", "b"], "ok": True},
                      {"trace_v": np.linspace(-1.0, 1.0, 50)}),
          Measurement("m2", "probe", {"level_v": 2.5, "n": 4, "ok": False})]  # fmt: skip
    records = Session(s.station, [], measurements=ms, record_types=[PROBE], provenance=prov, results=[RESULT])
    bases["records"] = write_session(records, root / "records")
    return bases


# --- mutations of a session directory: each returns True when it makes the directory invalid by construction ----

NASTY_TEXT = ["", " ", "nan", "NaN", "inf", "-inf", "1e999", "-0", "0", "-1", "5e-324", "1e-320", "1e308", "abc",
              "1,5", "0x10", "1_000", "\u0661", "../../etc/passwd", "<script>", "\x00", "P" * 200, "true", "[1]",
              "  7  ", "+3", "9" * 30, "3.0", "1e5", "[[[[1]]]]", '["a", 1]', "null"]  # fmt: skip
NASTY_JSON: list[Any] = [None, True, False, 0, -1, 1e308, 5e-324, 2**70, -(2**63), "abc", "", "../x", "<script>",
                         [], [1], [[[]]], {}, {"a": 1}, "NaN", 0.5, 100]  # fmt: skip
UNSAFE_IDS = ["../../etc/passwd", "<script>", "a/b", "P 1", "", "-x", "P" * 129, ".", "..", "p\u00e9"]


def _rows(d: Path) -> list[dict[str, str]]:
    with (d / "points.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


def _write_rows(d: Path, rows: list[dict[str, str]]) -> None:
    with (d / "points.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _vibration(d: Path, r: random.Random) -> tuple[list[dict[str, str]], dict[str, str]]:
    rows = _rows(d)
    return rows, r.choice([row for row in rows if row["kind"] == "vibration"])


def _doc(d: Path) -> dict:
    return json.loads((d / "session.json").read_text())


def _put_doc(d: Path, doc: dict) -> None:
    (d / "session.json").write_text(json.dumps(doc))


def _flip(path: Path, r: random.Random, head: int = 4096) -> None:
    data = bytearray(path.read_bytes())
    for _ in range(r.choice([1, 1, 2, 4, 16])):
        at = r.randrange(min(len(data), head) if r.random() < 0.7 else len(data))
        data[at] = r.randrange(256)
    if r.random() < 0.1:
        data = data[: r.randrange(len(data))]
    path.write_bytes(bytes(data))


def m_points_cell(d: Path, r: random.Random) -> bool:
    rows = _rows(d)
    row = r.choice(rows)
    column = r.choice(list(row))
    old = row[column]
    try:
        x = float(old)
        choices = [repr(x * r.choice([1 + 1e-9, 1 - 1e-6, 2.0, -1.0, 1e6])), repr(x + r.choice([-1.0, 1.0, 0.05]))]
    except ValueError:
        choices = []
    row[column] = r.choice(NASTY_TEXT + choices)
    _write_rows(d, rows)
    return False


def m_np_off(d: Path, r: random.Random) -> bool:
    rows, row = _vibration(d, r)
    row["Np"] = str(int(row["Np"]) + r.choice([-3, -2, -1, 1, 2, 3]))
    _write_rows(d, rows)
    return True


def m_t2_at_period(d: Path, r: random.Random) -> bool:
    rows, row = _vibration(d, r)
    period = 1.0 / float(row["freq_hz"])
    row["t2_s"] = repr(period)
    row["Tm_s"] = repr(float(row["t1_s"]) + (int(row["Np"]) - 1) * period)  # the identity holds with t2 = T
    _write_rows(d, rows)
    return True


def m_tiny_frequency(d: Path, r: random.Random) -> bool:
    rows, row = _vibration(d, r)
    row["freq_hz"] = r.choice(["5e-324", "1e-320", "1e-12", "0", "-10", "0.0"])
    _write_rows(d, rows)
    return True


def m_unsafe_point_id(d: Path, r: random.Random) -> bool:
    rows = _rows(d)
    r.choice(rows)["point_id"] = r.choice(UNSAFE_IDS)
    _write_rows(d, rows)
    return True


def m_points_structure(d: Path, r: random.Random) -> bool:
    path = d / "points.csv"
    lines = path.read_text().splitlines()
    how = r.randrange(7)
    if how == 0:
        lines.append(lines[-1])  # the same point twice
    elif how == 1:
        lines[0] = lines[0].replace("Np", "np")
    elif how == 2:
        lines = [line + ",x" for line in lines]
    elif how == 3:
        lines = [lines[0]]
    elif how == 4:
        path.write_bytes(b"\xef\xbb\xbf" + "\r\n".join(lines).encode() + b"\r\n")
        return False
    elif how == 5:
        path.write_bytes(bytes(r.randrange(256) for _ in range(200)))
        return False
    else:
        path.unlink()
        return True
    path.write_text("\n".join(lines) + "\n")
    return how in (0, 1)


def _paths(o: Any, at: tuple = ()) -> list[tuple]:
    out = [at]
    if isinstance(o, dict):
        for k, v in o.items():
            out += _paths(v, (*at, k))
    elif isinstance(o, list):
        for i, v in enumerate(o):
            out += _paths(v, (*at, i))
    return out


def _set(o: Any, at: tuple, value: Any) -> None:
    for k in at[:-1]:
        o = o[k]
    o[at[-1]] = value


def m_json_value(d: Path, r: random.Random) -> bool:
    doc = _doc(d)
    at = r.choice([p for p in _paths(doc) if p])
    _set(doc, at, r.choice(NASTY_JSON))
    _put_doc(d, doc)
    return False


def m_json_nonfinite(d: Path, r: random.Random) -> bool:
    text = (d / "session.json").read_text()
    numbers = list(re.finditer(r"(?<=: )-?\d+(\.\d+)?([eE][-+]?\d+)?", text))
    m = r.choice(numbers)
    (d / "session.json").write_text(text[: m.start()] + r.choice(["NaN", "Infinity", "-Infinity", "1e999"])
                                    + text[m.end():])  # fmt: skip
    return True


def m_json_bytes(d: Path, r: random.Random) -> bool:
    _flip(d / "session.json", r, head=1 << 20)
    return False


def m_declaration(d: Path, r: random.Random) -> bool:
    doc = _doc(d)
    decl = r.choice([*doc["measurements"][0]["fields"], *doc["measurements"][0]["arrays"]])
    decl[r.choice(["lo", "hi", "unit", "nullable", "lo_open", "ndim", "dtype", "name", "doc", "bogus"])] = r.choice(
        [*NASTY_JSON, float("nan")]
    )
    (d / "session.json").write_text(json.dumps(doc))  # NaN written as NaN: refused as JSON
    return False


def m_results(d: Path, r: random.Random) -> bool:
    doc = _doc(d)
    result = doc["results"][0]
    key = r.choice(["method", "created_utc", "result", "verdict"])
    result[key] = r.choice([*NASTY_JSON, "2026-12-01T19:00:00+00:00", "2999-01-01T00:00:00+00:00", "2026-12-02"])
    _put_doc(d, doc)
    return key == "verdict"


def m_raw_h5_bytes(d: Path, r: random.Random) -> bool:
    _flip(d / "raw.h5", r)
    return False


def m_raw_npz_bytes(d: Path, r: random.Random) -> bool:
    _flip(r.choice(sorted((d / "raw").glob("*.npz"))), r, head=1 << 20)
    return False


BAD_ARRAYS: list[tuple[str, Callable[[np.ndarray], np.ndarray], bool]] = [
    ("complex", lambda a: a + 1e-9j, True),
    ("nan", lambda a: np.where(np.arange(a.size) == a.size // 2, np.nan, a), True),
    ("2-D", lambda a: a.reshape(1, -1), True),
    ("text", lambda a: a.astype(str), True),
    ("object", lambda a: a.astype(object), True),
    ("reversed", lambda a: a[::-1], False),  # pulse_dir reversed is still +-1: not invalid by construction
    ("empty", lambda a: a[:0], False),
    ("short", lambda a: a[:-1], False),
    ("float32", lambda a: a.astype(np.float32), False),
    ("int8", lambda a: a.astype(np.int8), False),
    ("bool", lambda a: a.astype(bool), False),
]


def m_raw_array(d: Path, r: random.Random) -> bool:
    path = r.choice(sorted((d / "raw").glob("*.npz")))
    with np.load(path) as z:
        arrays = dict(z)
    key = r.choice(sorted(arrays))
    _, change, invalid = r.choice(BAD_ARRAYS)
    arrays[key] = change(arrays[key])
    np.savez(path, **arrays)  # allow_pickle (numpy's default): an object array is stored as a pickle
    return invalid


def m_h5_dataset(d: Path, r: random.Random) -> bool:
    with h5py.File(d / "raw.h5", "r+") as f:
        group = f[r.choice(sorted(f))]
        key = r.choice(sorted(group))
        a = group[key][()]
        _, change, invalid = r.choice([b for b in BAD_ARRAYS if b[0] != "object"])
        del group[key]
        b = change(a)
        group.create_dataset(key, data=b.astype(h5py.string_dtype()) if b.dtype.kind == "U" else b)
    return invalid


def m_measurement_cell(d: Path, r: random.Random) -> bool:
    path = d / "measurements" / "probe.csv"
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    row = r.choice(rows)
    row[r.choice(list(row))] = r.choice(NASTY_TEXT)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return False


def m_measurement_array(d: Path, r: random.Random) -> bool:
    (path,) = (d / "measurements" / "arrays").glob("*.npz")
    with np.load(path) as z:
        a = z["trace_v"]
    _name, change, invalid = r.choice([*BAD_ARRAYS, ("out of range", lambda a: a * 10.0, True)])
    np.savez(path, trace_v=change(a))
    return invalid


def m_stray_file(d: Path, r: random.Random) -> bool:
    how = r.randrange(4)
    if how == 0:
        os.symlink("/etc/passwd", d / "notes.txt")
    elif how == 1:
        os.mkfifo(d / "pipe")
    elif how == 2:
        (d / "raw").mkdir(exist_ok=True)
        np.savez(d / "raw" / "P999-stray.npz", grating_t=np.zeros(2), grating_z=np.zeros(2), pulse_t=np.zeros(2))
    else:
        os.symlink(d / "session.json", d / "points2.csv")
    return True


@dataclass(frozen=True)
class Mutation:
    name: str
    base: str  # the directory of make_bases it applies to
    apply: Callable[[Path, random.Random], bool]


IMPORT_MUTATIONS = [
    *(Mutation(f"points cell ({b})", b, m_points_cell) for b in ("h5", "npz")),
    Mutation("Np off by 1-3 periods", "h5", m_np_off),
    Mutation("t2 = T", "h5", m_t2_at_period),
    Mutation("freq_hz tiny or zero", "h5", m_tiny_frequency),
    Mutation("unsafe point_id", "npz", m_unsafe_point_id),
    Mutation("points.csv structure", "h5", m_points_structure),
    *(Mutation(f"session.json value ({b})", b, m_json_value) for b in ("h5", "records")),
    *(Mutation(f"session.json NaN/Infinity ({b})", b, m_json_nonfinite) for b in ("h5", "records")),
    Mutation("session.json bytes", "h5", m_json_bytes),
    Mutation("record declaration", "records", m_declaration),
    *(Mutation(f"results ({b})", b, m_results) for b in ("h5", "records")),
    Mutation("raw.h5 bytes", "h5", m_raw_h5_bytes),
    Mutation("raw.h5 dataset", "h5", m_h5_dataset),
    Mutation("raw/*.npz bytes", "npz", m_raw_npz_bytes),
    Mutation("raw/*.npz array", "npz", m_raw_array),
    Mutation("measurement cell", "records", m_measurement_cell),
    Mutation("measurement array", "records", m_measurement_array),
    *(Mutation(f"stray file ({b})", b, m_stray_file) for b in ("h5", "records")),
]


# --- what an accepted session must be (docs/interchange.md, restated) ---------------------------------------

SAFE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,127}")


def _finite_json(o: Any) -> bool:
    try:
        json.dumps(o, allow_nan=False)
    except (ValueError, TypeError):
        return False
    return True


def _real_array(a: Any, ndim: int | None = 1) -> str | None:
    a = np.asarray(a)
    if a.dtype.kind not in "biuf":
        return f"dtype {a.dtype}"
    if ndim is not None and a.ndim != ndim:
        return f"shape {a.shape}"
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        return "NaN or inf"
    return None


def session_defects(s: Session) -> list[str]:
    """What docs/interchange.md does not allow in the session (empty: a valid session)."""
    out = []
    stability = float((s.meta.get("timing") or {}).get("frequency_stability") or 1e-4)
    for p in s.points:
        if not SAFE_ID.fullmatch(p.point_id):
            out.append(f"point_id {p.point_id!r}")
        if not all(math.isfinite(v) for v in (p.start_s, p.position_deg, p.freq_hz, p.Tm_s)) or p.Tm_s <= 0:
            out.append(f"{p.point_id}: a number out of range")
        if p.kind == "vibration":
            if p.t1_s is None or p.t2_s is None or p.Np is None or not 1e-3 <= p.freq_hz <= 100:
                out.append(f"{p.point_id}: freq {p.freq_hz} / missing times")
                continue
            period = 1.0 / p.freq_hz
            turned = (p.Tm_s - p.t1_s + p.t2_s) / p.Np
            if not (0 < p.t1_s <= turned and 0 <= p.t2_s < turned * (1 - 1e-12)):
                out.append(f"{p.point_id}: t1 {p.t1_s!r} or t2 {p.t2_s!r} outside the period {turned!r}")
            residual = p.t1_s + p.Np * period - p.Tm_s - p.t2_s
            if abs(residual) > 1e-5 + stability * p.Np * period * (1 + 1e-9):
                out.append(f"{p.point_id}: Np {p.Np} leaves {residual!r} s")
        elif p.freq_hz != 0 or p.t1_s is not None:
            out.append(f"{p.point_id}: a static point with vibration times")
    for pid in s.raw:
        raw = s.raw[pid]
        for name in ("grating_t", "grating_z", "pulse_t", "pulse_dir", "reference_t"):
            a = getattr(raw, name)
            if a is not None and (bad := _real_array(a)):
                out.append(f"raw {pid} {name}: {bad}")
        if raw.pulse_t.size == 0:
            out.append(f"raw {pid}: no pulse edges")
    for rt in s.record_types:
        for f in (*rt.fields, *rt.arrays):
            bounds_ok = all(b is None or (type(b) in (int, float) and math.isfinite(b)) for b in (f.lo, f.hi))
            if not (bounds_ok and isinstance(f.unit, str) and type(f.nullable) is bool and type(f.ndim) is int):
                out.append(f"declaration {rt.kind}.{f.name}: {f}")
    for m in s.measurements:
        if not _finite_json(m.values):
            out.append(f"measurement {m.key}: values {m.values!r}")
        for name, a in m.arrays.items():
            if bad := _real_array(a, None):
                out.append(f"measurement {m.key} array {name}: {bad}")
    if not _finite_json(s.meta) or not _finite_json(s.results):
        out.append("meta or results hold NaN or inf")
    for r in s.results:
        if sorted(r) != ["created_utc", "method", "result"] or not SAFE_ID.fullmatch(str(r["method"])):
            out.append(f"result {r!r}")
        elif datetime.fromisoformat(r["created_utc"]).tzinfo is None:
            out.append(f"result time {r['created_utc']!r}")
    return out


# --- running a case -----------------------------------------------------------------------------------------


@dataclass
class Outcome:
    kind: str  # "accepted", "refused" (a clean refusal) or "traceback"
    detail: str = ""  # the refusal's message, the traceback's exception, or what an accepted input got wrong
    defects: list[str] = field(default_factory=list)  # accepted although invalid: what is wrong
    store_changed: bool = False  # a refusal that changed the store


def store_state(db: Path) -> tuple:
    """Everything an import could change: the sessions, their counts, and the files beside the store."""
    with SessionStore(db) as store:
        sessions = store.sessions()
    files = sorted(str(p.relative_to(db.parent)) for p in Path(f"{db}.raw").rglob("*")) if db.exists() else []
    return tuple(map(str, sessions)), tuple(files)


def import_case(bases: dict[str, Path], work: Path, db: Path, mutation: Mutation, seed: int) -> Outcome:
    """One mutated directory read and imported as `station import` does."""
    d = work / "case"
    if d.exists() or d.is_symlink():
        shutil.rmtree(d)
    shutil.copytree(bases[mutation.base], d)
    must_refuse = mutation.apply(d, random.Random(seed))
    before = store_state(db)
    try:
        session = read_session(d)
        with SessionStore(db) as store:
            store.import_session(session, content_hash(session))
    except CLEAN_REFUSALS as exc:
        return Outcome("refused", str(exc), store_changed=store_state(db) != before)
    except Exception as exc:
        return Outcome("traceback", f"{type(exc).__name__}: {exc}")
    try:
        defects = session_defects(session)
    except Exception as exc:  # a value of a type the restatement does not expect: not a valid session either
        defects = [f"{type(exc).__name__} in session_defects: {exc}"]
    if must_refuse:
        defects.append(f"{mutation.name}: invalid by construction, accepted")
    return Outcome("accepted", defects=defects)


# --- procedure files --------------------------------------------------------------------------------------

NASTY_TOML = ["nan", "inf", "-inf", "-1", "0", "1e308", "-1e308", "5e-324", '"abc"', '""', "[]", "[[1]]", "true",
              "false", "{a = 1}", "1979-05-27", "07:32:00", "0x7fffffffffffffff", "9223372036854775807", '["a"]',
              "[1, 2, 3]", "[nan]", "[1e400]", "1.5", "3.0", "'''x'''", "[1, [2]]"]  # fmt: skip


def _spec_of(text: str) -> Any:
    library = load_library()
    try:
        return library[tomllib.loads(text)["procedure"]]
    except (tomllib.TOMLDecodeError, KeyError):
        return None


def _param_lines(text: str) -> list[tuple[int, str]]:
    lines = text.splitlines()
    start = lines.index("[params]") if "[params]" in lines else len(lines)
    return [(i, lines[i].split("=")[0].strip()) for i in range(start + 1, len(lines)) if "=" in lines[i]]


def _set_param(text: str, name: str, value: str) -> str:
    lines = text.splitlines()
    for i, key in _param_lines(text):
        if key == name:
            lines[i] = f"{name} = {value}"
            return "\n".join(lines) + "\n"
    if "[params]" not in lines:
        lines.append("[params]")
    return "\n".join([*lines, f"{name} = {value}"]) + "\n"


def p_value(text: str, r: random.Random) -> tuple[bytes, bool]:
    spec = _spec_of(text)
    name = r.choice([p.name for p in spec.params]) if spec and spec.params else "x"
    return _set_param(text, name, r.choice(NASTY_TOML)).encode(), False


def p_out_of_range(text: str, r: random.Random) -> tuple[bytes, bool]:
    spec = _spec_of(text)
    ranged = [p for p in spec.params if p.kind in (int, float, list) and (p.min is not None or p.max is not None)]
    if not ranged:
        return text.encode(), False
    p = r.choice(ranged)
    over = [p.max + max(1.0, abs(p.max))] if p.max is not None else []
    under = [p.min - max(1.0, abs(p.min))] if p.min is not None else []
    v = r.choice(over + under)
    literal = repr(int(v) if p.kind is int else float(v))
    return _set_param(text, p.name, f"[{literal}]" if p.kind is list else literal).encode(), True


def p_wrong_type(text: str, r: random.Random) -> tuple[bytes, bool]:
    spec = _spec_of(text)
    if not spec or not spec.params:
        return text.encode(), False
    p = r.choice(spec.params)
    wrong = {float: ['"1.0"', "true", "[1.0]", "{a = 1}"], int: ['"3"', "true", "2.5", "[3]"],
             list: ['"1,2"', "1.0", "[]", '["a"]', "[true]", "[[1.0]]"],
             str: ["1", "true", "[1]", '"no-such-choice-x"'], bool: ['"yes"', "1", "[true]"]}[p.kind]  # fmt: skip
    choices = [w for w in wrong if not (p.kind is str and not p.choices and w.startswith('"'))]
    return _set_param(text, p.name, r.choice(choices)).encode(), True


def p_unknown_key(text: str, r: random.Random) -> tuple[bytes, bool]:
    if r.random() < 0.5:
        return _set_param(text, "bogus_param", "1").encode(), True
    return ('colour = "red"\n' + text).encode(), True


def p_procedure_name(text: str, r: random.Random) -> tuple[bytes, bool]:
    name = r.choice(['"no.such.procedure"', "1", "[]", '""', '"../../etc/passwd"', "{a = 1}"])
    return re.sub(r"^procedure = .*$", f"procedure = {name}", text, count=1, flags=re.M).encode(), True


def p_bytes(text: str, r: random.Random) -> tuple[bytes, bool]:
    data = bytearray(text.encode())
    for _ in range(r.choice([1, 2, 8])):
        data[r.randrange(len(data))] = r.randrange(256)
    if r.random() < 0.2:
        data = data[: r.randrange(len(data))]
    return bytes(data), False


def p_deep(text: str, r: random.Random) -> tuple[bytes, bool]:
    spec = _spec_of(text)
    name = r.choice([p.name for p in spec.params]) if spec and spec.params else "x"
    n = r.choice([3, 50, 500, 3000])
    value = "[" * n + "1" + "]" * n if r.random() < 0.5 else "{a = " * n + "1" + "}" * n
    return _set_param(text, name, value).encode(), True


def p_huge_list(text: str, r: random.Random) -> tuple[bytes, bool]:
    spec = _spec_of(text)
    lists = [p for p in spec.params if p.kind is list] if spec else []
    if not lists:
        return text.encode(), False
    p = r.choice(lists)
    return _set_param(text, p.name, "[" + ", ".join(["1.0"] * r.choice([1000, 100_000])) + "]").encode(), False


def p_serial(text: str, r: random.Random) -> tuple[bytes, bool]:
    value = r.choice(['"PIGA-1"', "1", "[]", "true", '""', '"\\u0000"', "{a = 1}"])
    return (f"instrument_serial = {value}\n" + text).encode(), value not in ('"PIGA-1"', '""', '"\\u0000"')


def p_duplicate(text: str, r: random.Random) -> tuple[bytes, bool]:
    lines = _param_lines(text)
    if not lines:
        return text.encode(), False
    i, _ = r.choice(lines)
    all_lines = text.splitlines()
    return "\n".join([*all_lines, all_lines[i]]).encode() + b"\n", True


PROCEDURE_MUTATIONS: list[tuple[str, Callable[[str, random.Random], tuple[bytes, bool]]]] = [
    ("parameter value", p_value),
    ("parameter out of range", p_out_of_range),
    ("parameter of the wrong type", p_wrong_type),
    ("unknown key", p_unknown_key),
    ("procedure name", p_procedure_name),
    ("bytes", p_bytes),
    ("deep nesting", p_deep),
    ("huge list", p_huge_list),
    ("instrument_serial", p_serial),
    ("duplicate key", p_duplicate),
]


def params_defects(spec: Any, params: dict[str, Any], serial: Any) -> list[str]:
    """What a procedure's declared parameters do not allow in `params` (empty: valid)."""
    out = []
    if sorted(params) != sorted(p.name for p in spec.params):
        out.append(f"parameters {sorted(params)}")
    for p in spec.params:
        v = params.get(p.name)
        if v is None:
            if p.required or p.default is not None:
                out.append(f"{p.name} missing")
            continue
        items = v if p.kind is list else [v]
        if p.kind is list and (not isinstance(v, list) or not v):
            out.append(f"{p.name} = {v!r}: not a non-empty list")
            continue
        kind = float if p.kind is list else p.kind
        for x in items:
            if kind is float and not (type(x) is float and math.isfinite(x)):
                out.append(f"{p.name} = {x!r}: not a finite float")
            elif kind is int and type(x) is not int:
                out.append(f"{p.name} = {x!r}: not an int")
            elif kind in (str, bool) and type(x) is not kind:
                out.append(f"{p.name} = {x!r}: not {kind.__name__}")
            elif kind in (int, float) and ((p.min is not None and x < p.min) or (p.max is not None and x > p.max)):
                out.append(f"{p.name} = {x!r}: outside [{p.min}, {p.max}]")
            elif p.choices and x not in p.choices:
                out.append(f"{p.name} = {x!r}: not one of {p.choices}")
    if not isinstance(serial, str):
        out.append(f"instrument_serial {serial!r}")
    return out


def procedure_case(work: Path, index: int, seed: int) -> Outcome:
    """One mutated procedure file read as `station run FILE` reads it (parameters, then the instrument serial)."""
    r = random.Random(seed)
    name, mutate = PROCEDURE_MUTATIONS[index]
    data, must_refuse = mutate(r.choice(PROCEDURE_FILES).read_text(), r)
    path = work / "procedure.toml"
    path.write_bytes(data)
    try:
        spec, params = load_procedure_file(path)
        serial = procedure_file_serial(path)
    except InputError as exc:
        return Outcome("refused", str(exc))
    except Exception as exc:
        return Outcome("traceback", f"{type(exc).__name__}: {str(exc)[:200]}")
    try:
        defects = params_defects(spec, params, serial)
    except Exception as exc:  # a value of a type the restatement does not expect: not valid parameters either
        defects = [f"{type(exc).__name__} in params_defects: {exc}"]
    if must_refuse:
        defects.append(f"{name}: invalid by construction, accepted")
    return Outcome("accepted", defects=defects)


# --- the bounded campaign -------------------------------------------------------------------------------------

# 250 import and 250 procedure cases: about 15 s on the 2-core standard machine (the bench runs thousands)
FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])  # fmt: skip


@pytest.fixture(scope="module")
def bases(tmp_path_factory) -> dict[str, Path]:
    return make_bases(tmp_path_factory.mktemp("bases"))


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("work")


def test_every_base_is_valid_and_imports(bases, work):
    """The starting points are themselves accepted (else every mutation's refusal would prove nothing)."""
    for name, d in bases.items():
        assert session_defects(read_session(d)) == [], name
    for path in PROCEDURE_FILES:
        spec, params = load_procedure_file(path)
        assert params_defects(spec, params, procedure_file_serial(path)) == [], path.name


def test_the_oracles_catch_what_they_must():
    """session_defects and params_defects are not vacuous: a hand-made invalid value is reported."""
    s = simulate_session(multiposition_plan([0.0], [10.0], window_s=1.0), TwinConfig(), seed=3)
    v = next(p for p in s.points if p.kind == "vibration")
    bad = [type(v)(**(vars(v) | {"Np": v.Np + 1})), type(v)(**(vars(v) | {"point_id": "../x"}))]
    assert len(session_defects(Session(s.station, bad))) == 2
    spec, params = load_procedure_file(PROCEDURE_FILES[0])
    p = next(p for p in spec.params if p.max is not None and p.kind is not list)
    assert params_defects(spec, params | {p.name: p.max * 2 + 1}, "") != []


@settings(FUZZ, max_examples=250)
@given(index=st.integers(0, len(IMPORT_MUTATIONS) - 1), seed=st.integers(0, 2**32 - 1))
def test_import_fuzz(bases, work, index, seed):
    outcome = import_case(bases, work, work / "store.sqlite", IMPORT_MUTATIONS[index], seed)
    assert outcome.kind != "traceback", (IMPORT_MUTATIONS[index].name, seed, outcome.detail)
    assert not outcome.defects, (IMPORT_MUTATIONS[index].name, seed, outcome.defects)
    assert not outcome.store_changed, (IMPORT_MUTATIONS[index].name, seed, outcome.detail)


@settings(FUZZ, max_examples=250)
@given(index=st.integers(0, len(PROCEDURE_MUTATIONS) - 1), seed=st.integers(0, 2**32 - 1))
def test_procedure_file_fuzz(work, index, seed):
    outcome = procedure_case(work, index, seed)
    assert outcome.kind != "traceback", (PROCEDURE_MUTATIONS[index][0], seed, outcome.detail)
    assert not outcome.defects, (PROCEDURE_MUTATIONS[index][0], seed, outcome.defects)
