"""Every procedure's session survives the round trip: recorded through the simulated station (engine, drivers,
emulators), exported as piga-session/1, imported into a fresh store: the same store content (points, raw streams,
typed measurements and their arrays, record types, provenance, results, procedure and parameters).

Short parameters keep each session to a few seconds of wall time (all of them about a minute on 2 cores)."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from devices.config import load_station_config
from devices.station import simulated_station
from engine.planning import plan_procedure
from engine.registry import load_procedure_file
from engine.runner import Engine, State
from models.config import default_twin
from station.interchange import content_hash, read_session, write_session
from station.provenance import PROVENANCE_KEYS
from station.store import SessionStore

CONFIG = Path(__file__).resolve().parents[1] / "config"
# procedure file -> (station file, parameters that shorten it)
RUNS = {
    "seed000_baseline": ("station-sim", {"positions_deg": [0, 180], "freqs_hz": [10], "window_s": 10}),
    "seed000_frequency_stability": ("station-sim", {"freqs_hz": [5, 10], "periods": 4, "settle_s": 1}),
    "seed000_integral": ("station-sim", {"positions_deg": [0, 180], "freqs_hz": [10], "window_s": 10, "raw": True}),
    "seed000_multi_frequency": ("station-sim", {"positions_deg": [0, 180], "freqs_hz": [9, 10], "window_s": 10}),
    "seed000_parasitic_rotation": (
        "station-gradiometer-sim", {"freq_hz": 0.5, "turns": 1, "readings_per_turn": 8, "settle_s": 1}
    ),
    "seed000_parasitic_translation": ("station-sim", {"freqs_hz": [5, 10], "periods": 2, "settle_s": 1}),
    "seed000_planning": ("station-sim", {"positions_deg": [0, 90, 180, 270], "freqs_hz": [10], "window_s": 10}),
    "seed000_self_alignment": ("station-sim", {"window_s": 10}),
    "seed001_tumble": ("station-tumble-sim", {"temperatures_c": [20, 25], "cycles": 1, "ramp_c_per_min": 5,
                                              "soak_s": 60, "dwell_s": 1, "samples": 2}),
    "seed002_g_sensitive": ("station-shaker-sim", {"poses": [1, 2], "align_s": 10, "vibrate_s": 10,
                                                   "verify_sine_poses": [5], "verify_random_poses": [10]}),
    "seed002_quick": ("station-shaker-sim", {"poses": [1, 2], "align_s": 10, "vibrate_s": 10, "remount_s": 10}),
    "seed003_gravity_field": ("station-dual-sim", {"precession_rev": 1 / 64, "alignment_rev": 1 / 64, "settle_s": 0.0,
                                                   "setup1_n": 6, "setup2_n": 6, "calibration_schemes": "none"}),
    "seed003_planning": ("station-dual-sim", {}),
    "seed004_suppression": ("station-electronics-sim", {"offsets_arcsec": [-2.0, -1.0, 0.0, 1.0],
                                                        "freqs_hz": [8.0, 10.0], "window_s": 10.0,
                                                        "verify_window_s": 10.0}),
}  # fmt: skip


def test_every_procedure_file_is_covered():
    assert sorted(RUNS) == sorted(p.stem for p in (CONFIG / "procedures").glob("*.toml"))


def _record(name: str, db: Path) -> str:
    station, shorter = RUNS[name]
    cfg = load_station_config(CONFIG / f"{station}.toml")
    path = CONFIG / "procedures" / f"{name}.toml"
    spec, _ = load_procedure_file(path)
    params = spec.validate(tomllib.loads(path.read_text()).get("params", {}) | shorter)
    plan = plan_procedure(spec, params, cfg.station_model())
    with simulated_station(cfg, default_twin(), seed=11, speed=1000.0) as sim, SessionStore(db) as store:
        engine = Engine(sim.devices, store)
        uid, _ = engine.run(spec, plan, instrument_serial="PIGA-RT-1")
        assert engine.progress.state == State.FINISHED, engine.progress.faults
        store.add_result(uid, "round-trip", {"kz": 0.56, "names": ["kz"], "n": len(plan.measurements)})
    return uid


def _same_arrays(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("name", sorted(RUNS))
def test_export_then_import_gives_the_same_store_content(tmp_path, name):
    uid = _record(name, tmp_path / "station.sqlite")
    with SessionStore(tmp_path / "station.sqlite") as store:
        before = store.load_session(uid)
        (row,) = store.sessions()
    exported = write_session(before, tmp_path / "export")
    with SessionStore(tmp_path / "other.sqlite") as other:
        new_uid, created = other.import_session(read_session(exported), content_hash(read_session(exported)))
        assert created
        again = other.import_session(read_session(exported), content_hash(read_session(exported)))
        assert again == (new_uid, False)  # the same content is recognised, not stored twice
        after = other.load_session(new_uid)
        (new_row,) = other.sessions()
    assert (new_row["procedure"], new_row["n_points"], new_row["n_measurements"], new_row["status"]) == (
        row["procedure"], row["n_points"], row["n_measurements"], "imported"
    )  # fmt: skip
    assert after.station == before.station and after.notes == before.notes
    assert after.points == before.points
    assert sorted(after.raw) == sorted(before.raw)
    for pid in before.raw:
        _same_arrays(vars(after.raw[pid]), vars(before.raw[pid]))
    assert [rt.to_json() for rt in after.record_types] == [rt.to_json() for rt in before.record_types]
    assert [(m.key, m.kind, m.values) for m in after.measurements] == [
        (m.key, m.kind, m.values) for m in before.measurements
    ]
    for a, b in zip(after.measurements, before.measurements, strict=True):
        _same_arrays(a.arrays, b.arrays)
    assert after.provenance == before.provenance
    assert set(before.provenance) >= set(PROVENANCE_KEYS)
    assert before.provenance["station_id"] == RUNS[name][0] and before.provenance["simulated"] is True
    assert before.provenance["seed"] == 11 and before.provenance["instrument_serial"] == "PIGA-RT-1"
    assert [r["result"] for r in after.results] == [r["result"] for r in before.results]
    for key in ("procedure", "params", "instrument_serial"):
        assert after.meta[key] == before.meta[key], key
    # every measurement is typed by its kind's declaration (ints stay ints, floats floats)
    types = {rt.kind: rt for rt in before.record_types}
    for m in before.measurements:
        for f in types[m.kind].fields:
            v = m.values.get(f.name)
            if v is not None and f.ndim == 0:
                assert type(v) is {"float64": float, "int64": int, "str": str, "bool": bool}[f.dtype], (m.key, f.name)
