"""Issue 30 (3): what an import used to crash on, or accepted although it is invalid, is a clean refusal naming the
file, the field and the value; every refused import leaves the store as it was.

The cases are those of the issue: record declarations with a bound or key of the wrong type, an .npy header that is
not a Python literal, a frequency whose period is infinite, t2 equal to the period, complex arrays, an Np off by one
or two periods on a 4484-period window, unsafe point ids, results with NaN or computed before the session was
recorded, empty pulse records.
"""

import csv
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from session_files import refused

from station.interchange import Timing, read_session, write_session
from station.records import Field, RecordError, RecordType
from station.session import Measurement
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session

POINT_COLUMNS = ["point_id", "sequence", "start_s", "position_deg", "freq_hz", "kind", "pulses", "Tm_s", "t1_s", "t2_s",
                 "Np"]  # fmt: skip
# A seed-000-like window: 8 Hz, 4484 periods (560.5 s); t1 + Np T - Tm - t2 = 0 exactly in binary for these values
FREQ, NP, T1, T2 = 8.0, 4484, 0.0625, 0.03125
PERIOD = 1.0 / FREQ
TM = T1 + NP * PERIOD - T2


@pytest.fixture(scope="module")
def session():
    return simulate_session(multiposition_plan([0.0], [10.0], window_s=1.0), TwinConfig(), seed=3, raw=True)


@pytest.fixture
def good(tmp_path, session) -> Path:
    return write_session(session, tmp_path / "s")


def _edit_json(directory: Path, edit) -> None:
    path = directory / "session.json"
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


def _one_point(directory: Path, **cells) -> None:
    """points.csv holding one vibration point (the long window above), with `cells` replaced (as text)."""
    row = {"point_id": "P001-0deg-v8", "sequence": 0, "start_s": 0.0, "position_deg": 0.0, "freq_hz": FREQ,
           "kind": "vibration", "pulses": 819200, "Tm_s": repr(TM), "t1_s": repr(T1), "t2_s": repr(T2),
           "Np": NP}  # fmt: skip
    row |= cells
    with (directory / "points.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=POINT_COLUMNS)
        w.writeheader()
        w.writerow(row)
    if (directory / "raw.h5").exists():
        (directory / "raw.h5").unlink()


# --- record declarations: tracebacks and accepted-invalid values, now refused --------------------------------


@pytest.mark.parametrize(
    ("field", "key", "shown"),
    [
        ({"lo": "abc"}, "lo", "'abc'"),
        ({"hi": [1]}, "hi", "[1]"),
        ({"nullable": "no"}, "nullable", "'no'"),
        ({"unit": {"si": "V"}}, "unit", "{'si': 'V'}"),
        ({"ndim": "x"}, "ndim", "'x'"),
        ({"ndim": True}, "ndim", "True"),
        ({"lo": 5.0, "hi": 1.0}, "hi", "1.0"),
        ({"lo": True}, "lo", "True"),
        ({"doc": 7}, "doc", "7"),
    ],
    ids=[
        "lo-text",
        "hi-list",
        "nullable-text",
        "unit-object",
        "ndim-text",
        "ndim-bool",
        "lo-above-hi",
        "lo-bool",
        "doc-number",
    ],
)
@pytest.mark.parametrize("group", ["fields", "arrays"])
def test_a_declaration_of_the_wrong_type_is_refused_naming_key_and_value(good, tmp_path, field, key, shown, group):
    declared = {"name": "level_v", "dtype": "float64", "unit": "V"} | field
    doc = {"kind": "probe", "fields": [], "arrays": []} | {group: [declared]}
    _edit_json(good, lambda d: d.__setitem__("measurements", [doc]))
    refused(good, tmp_path, "session.json", "measurements[0]", "field 'level_v'", f"{key!r} = {shown}")


def test_nan_and_infinity_anywhere_in_session_json_are_refused(good, tmp_path):
    text = (good / "session.json").read_text()
    for bad in ("NaN", "Infinity", "-Infinity", "1e999"):
        (good / "session.json").write_text(text.replace('"notes": ""', f'"notes": "", "lo": {bad}'))
        refused(good, tmp_path, "session.json", repr(bad), "JSON numbers are finite doubles")


def test_a_declared_bound_that_is_nan_never_reaches_a_record_type():
    with pytest.raises(RecordError, match=r"field 'x': field 'lo' = nan: not allowed \(allowed: a finite number"):
        Field("x", "float64", lo=float("nan"))
    with pytest.raises(RecordError, match=r"'unit' = 3"):
        RecordType.from_json({"kind": "k", "fields": [{"name": "x", "dtype": "float64", "unit": 3}]}, "here")


# --- arrays ----------------------------------------------------------------------------------------------------


def _npz_with_header(path: Path, header: bytes) -> None:
    """An .npz whose pulse_t member has `header` as its .npy header (magic, version 1.0, length)."""
    body = b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("pulse_t.npy", body)
    path.write_bytes(buf.getvalue())


@pytest.mark.parametrize("header", [b"{'descr': '<f8', \n", b"{'descr': '<f8' 'fortran_order'}\n", b"(((\n"],
                         ids=["unterminated", "not-a-dict", "tokenizer"])  # fmt: skip
def test_an_npy_header_that_is_not_a_literal_is_a_clean_refusal(good, session, tmp_path, header):
    pid = next(iter(session.raw))
    (good / "raw.h5").unlink()
    (good / "raw").mkdir()
    _npz_with_header(good / "raw" / f"{pid}.npz", header)
    refused(good, tmp_path, f"raw/{pid}.npz", "'pulse_t'", "not a readable .npy array")


def _raw_npz(good: Path, session, pid: str, **replace) -> None:
    (good / "raw.h5").unlink(missing_ok=True)
    (good / "raw").mkdir(exist_ok=True)
    r = session.raw[pid]
    arrays = {"grating_t": r.grating_t, "grating_z": r.grating_z, "pulse_t": r.pulse_t, "pulse_dir": r.pulse_dir}
    np.savez(good / "raw" / f"{pid}.npz", **(arrays | replace))


def test_complex_raw_arrays_are_refused_not_cut_to_their_real_part(good, session, tmp_path):
    pid = next(iter(session.raw))
    _raw_npz(good, session, pid, pulse_t=session.raw[pid].pulse_t + 1e-9j)
    refused(good, tmp_path, f"raw/{pid}.npz", "'pulse_t'", "dtype complex128", "only a real numeric dtype")


def test_a_complex_measurement_array_is_refused_by_its_declaration():
    rt = RecordType("probe", (), arrays=(Field("trace_v", "float64", "V"),))
    m = Measurement("m1", "probe", {}, {"trace_v": np.arange(3) + 1j})
    with pytest.raises(RecordError, match=r"field 'trace_v' = 'dtype complex128'.*a finite number \(V\)"):
        m.checked(rt)


@pytest.mark.parametrize(
    ("replace", "column", "message"),
    [
        ({"pulse_t": np.zeros(0), "pulse_dir": np.zeros(0)}, "pulse_t", "empty: a vibration point's record holds"),
        ({"grating_t": np.zeros(0), "grating_z": np.zeros(0)}, "grating_t", "and the table's motion"),
        ({"pulse_dir": np.ones(3)}, "pulse_dir", "one direction per pulse edge"),
        ({"pulse_dir": None}, "pulse_dir", "each value must be +1 or -1"),
    ],
    ids=["no-pulses", "no-grating", "short-directions", "zero-directions"],
)
def test_empty_records_and_bad_directions_are_refused(good, session, tmp_path, replace, column, message):
    pid = next(p.point_id for p in session.points if p.kind == "vibration")
    if replace.get("pulse_dir", 0) is None:
        replace = {"pulse_dir": np.zeros(session.raw[pid].pulse_t.size)}
    _raw_npz(good, session, pid, **replace)
    refused(good, tmp_path, f"raw/{pid}.npz", repr(column), message)


# --- points.csv: the period identity, the period's bounds, point ids ---------------------------------------------


def test_the_long_window_imports_exactly_as_stated(good):
    _one_point(good)
    (p,) = read_session(good).points
    assert (p.Tm_s, p.t1_s, p.t2_s, p.Np) == (TM, T1, T2, NP)


@pytest.mark.parametrize("off", [-2, -1, 1, 2])
def test_np_off_by_one_or_two_periods_is_refused(good, tmp_path, off):
    _one_point(good, Np=NP + off)
    refused(good, tmp_path, "points.csv row 2, column 'Np'", f"value '{NP + off}'", "Np is not the whole periods")


def test_a_frequency_error_within_the_stated_stability_is_accepted_and_beyond_it_refused(good, tmp_path):
    """The default allows |eps_f| <= 1e-4: 0.9e-4 imports, 1.1e-4 does not until session.json states 2e-4."""
    for eps in (0.9e-4, -0.9e-4):
        _one_point(good, Tm_s=repr(TM + eps * NP * PERIOD))
        assert read_session(good).points[0].Np == NP
    _one_point(good, Tm_s=repr(TM + 1.1e-4 * NP * PERIOD))
    refused(good, tmp_path, "column 'Np'", "a frequency error up to 0.0001")
    _edit_json(good, lambda d: d.__setitem__("timing", {"frequency_stability": 2e-4}))
    assert read_session(good).points[0].Np == NP


def test_timing_statements_are_checked(good, tmp_path):
    _edit_json(good, lambda d: d.__setitem__("timing", {"frequency_stability": 0.01}))
    refused(good, tmp_path, "session.json", "'timing.frequency_stability', value 0.01", "in [0, 0.0005]")
    _edit_json(good, lambda d: d.__setitem__("timing", {"timing_sigma_s": "1 us"}))
    refused(good, tmp_path, "'timing.timing_sigma_s', value '1 us'")
    stated = Timing.from_meta({"timing": {"timing_sigma_s": 1e-6, "timer_resolution_s": 0.0}}, "session.json")
    assert stated.frequency_stability == 1e-4  # the default where not stated
    assert stated.tolerance_s(0.0) == pytest.approx(6 * 2**0.5 * 1e-6, rel=1e-12)


def test_t2_equal_to_the_period_is_refused(good, tmp_path):
    """t2 in [0, T): a closing crossing at T after Tm is the next one's t2 = 0 (the same times with Np + 1)."""
    _one_point(good, t2_s=repr(PERIOD), Tm_s=repr(T1 + NP * PERIOD - PERIOD), Np=NP)
    refused(good, tmp_path, "column 't2_s'", f"value '{PERIOD!r}'", "t2_s must lie in [0, T)")
    _one_point(good, t2_s="0.0", Tm_s=repr(T1 + NP * PERIOD), Np=NP)
    assert read_session(good).points[0].t2_s == 0.0


def test_t1_beyond_the_period_the_table_turned_at_is_refused(good, tmp_path):
    _one_point(good, t1_s=repr(PERIOD * 1.00005), Tm_s=repr(PERIOD * 1.00005 + NP * PERIOD - T2))
    refused(good, tmp_path, "column 't1_s'", "t1_s must lie in (0, T], T = (Tm - t1 + t2) / Np")


@pytest.mark.parametrize("pid", ["../../etc/passwd", "<script>alert(1)</script>", "P 1", "a/b", "P" * 129, "-x"])
def test_point_ids_must_be_safe_names(good, tmp_path, pid):
    _one_point(good, point_id=pid)
    refused(good, tmp_path, "points.csv row 2, column 'point_id'", repr(pid), "1-128 letters, digits, . _ + -")


# --- results ---------------------------------------------------------------------------------------------------


RESULT = {"method": "integral", "created_utc": "2026-12-01T20:00:00.000+00:00", "result": {"kz": 0.56}}


@pytest.mark.parametrize(
    ("result", "parts"),
    [
        ({"method": "../x"}, ("'results[0].method'", "'../x'", "a method name")),
        ({"method": "integral\n"}, ("'results[0].method'", "'integral\\n'", "a method name")),
        ({"created_utc": "yesterday"}, ("'results[0].created_utc'", "'yesterday'", "ISO 8601")),
        ({"created_utc": "2026-12-01T20:00:00"}, ("'results[0].created_utc'", "with its UTC offset")),
        ({"created_utc": "2026-11-01T00:00:00+00:00"}, ("'results[0].created_utc'", "after the session was recorded")),
        ({"created_utc": "2999-01-01T00:00:00+00:00"}, ("'results[0].created_utc'", "not in the future")),
        ({"result": [1, 2]}, ("'results[0].result'", "must be a JSON object")),
        ({"verdict": "passed"}, ("'results[0]'", "exactly the keys method, created_utc, result")),
    ],
    ids=[
        "method",
        "method-newline",
        "time-text",
        "time-naive",
        "before-recording",
        "future",
        "not-object",
        "extra-key",
    ],
)
def test_imported_results_are_checked_like_the_stores_own(good, tmp_path, result, parts):
    def edit(doc):
        doc["provenance"] = {"created_utc": "2026-12-01T19:54:18.120+00:00"}
        doc["results"] = [RESULT | result]

    _edit_json(good, edit)
    refused(good, tmp_path, "session.json", *parts)


def test_a_result_with_nan_is_refused(good, tmp_path):
    doc = json.loads((good / "session.json").read_text())
    doc["results"] = [RESULT | {"result": {"kz": "@"}}]
    (good / "session.json").write_text(json.dumps(doc).replace('"@"', "NaN"))
    refused(good, tmp_path, "session.json", "'NaN'", "JSON numbers are finite doubles")


def test_valid_results_are_kept(good):
    _edit_json(good, lambda d: d.__setitem__("results", [RESULT]))
    assert read_session(good).results == [RESULT]
