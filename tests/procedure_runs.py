"""Every procedure file with the station it needs and parameters that shorten its session to a few seconds of
wall time, recorded through the simulated station (engine, drivers, emulators): the round-trip and the
determinism tests share them."""

import tomllib
from pathlib import Path
from typing import Any

from drivers.config import load_station_config
from drivers.station import simulated_station
from station.engine.planning import plan_procedure
from station.engine.registry import ProcedureSpec, load_procedure_file
from station.engine.runner import Engine, State
from station.store import SessionStore
from station.twin.config import TwinConfig, default_twin

CONFIG = Path(__file__).resolve().parents[1] / "config"
# procedure file -> (station file, parameters that shorten it)
RUNS = {
    "integral_precession.integer_periodic_vibration": (
        "vibration-sim", {"positions_deg": [0, 180], "freqs_hz": [10], "window_s": 10}),
    "integral_precession.frequency_stability": ("vibration-sim", {"freqs_hz": [5, 10], "periods": 4, "settle_s": 1}),
    "integral_precession": (
        "vibration-sim", {"positions_deg": [0, 180], "freqs_hz": [10], "window_s": 10, "raw": True}),
    "integral_precession.multi_frequency": (
        "vibration-sim", {"positions_deg": [0, 180], "freqs_hz": [9, 10], "window_s": 10}),
    "integral_precession.parasitic_rotation": (
        "gradiometer-sim", {"freq_hz": 0.5, "turns": 1, "readings_per_turn": 8, "settle_s": 1}
    ),
    "integral_precession.parasitic_translation": ("vibration-sim", {"freqs_hz": [5, 10], "periods": 2, "settle_s": 1}),
    "integral_precession.planning": (
        "vibration-sim", {"positions_deg": [0, 90, 180, 270], "freqs_hz": [10], "window_s": 10}),
    "integral_precession.self_alignment": ("vibration-sim", {"window_s": 10}),
    "tumble": ("tumble-sim", {"temperatures_c": [20, 25], "cycles": 1, "ramp_c_per_min": 5,
                              "soak_s": 60, "dwell_s": 1, "samples": 2}),
    "rlg_g_sensitivity": ("shaker-sim", {"poses": [1, 2], "align_s": 10, "vibrate_s": 10,
                                         "verify_sine_poses": [5], "verify_random_poses": [10]}),
    "rlg_g_sensitivity-quick": ("shaker-sim", {"poses": [1, 2], "align_s": 10, "vibrate_s": 10, "remount_s": 10}),
    "multiposition": ("dual-sim", {"precession_rev": 1 / 64, "alignment_rev": 1 / 64, "settle_s": 0.0,
                                   "setup1_n": 6, "setup2_n": 6, "calibration_schemes": "none"}),
    "multiposition.planning": ("dual-sim", {}),
    "nonlinear_suppression": ("electronics-sim", {"offsets_arcsec": [-2.0, -1.0, 0.0, 1.0],
                                                  "freqs_hz": [8.0, 10.0], "window_s": 10.0,
                                                  "verify_window_s": 10.0}),
}  # fmt: skip


UNSTABLE = {"created_utc", "provenance", "uid", "session_uid", "store_uid"}  # not part of the determinism promise


def stable(doc: Any) -> Any:
    """doc without the keys a run's identity and wall clock set (UNSTABLE), at any depth."""
    if isinstance(doc, dict):
        return {k: stable(v) for k, v in doc.items() if k not in UNSTABLE}
    if isinstance(doc, list):
        return [stable(v) for v in doc]
    return doc


def procedure_spec(name: str) -> ProcedureSpec:
    spec, _ = load_procedure_file(CONFIG / "procedures" / f"{name}.toml")
    return spec


def record(name: str, db: Path, twin: TwinConfig | None = None) -> str:
    """The shortened session of procedure file `name` (seed 11, default_twin unless told) stored in `db`; its uid.
    On the simulated station (discrete-event clock) as fast as the CPU allows, the calling thread its party."""
    station, shorter = RUNS[name]
    cfg = load_station_config(CONFIG / "stations" / f"{station}.toml")
    path = CONFIG / "procedures" / f"{name}.toml"
    spec = procedure_spec(name)
    params = spec.validate(tomllib.loads(path.read_text()).get("params", {}) | shorter)
    plan = plan_procedure(spec, params, cfg.station_model())
    with (
        simulated_station(cfg, twin or default_twin(), seed=11) as sim,
        SessionStore(db) as store,
        sim.devices.clock.party("engine"),
    ):
        engine = Engine(sim.devices, store)
        uid, _ = engine.run(spec, plan, instrument_serial="PIGA-RT-1")
        assert engine.progress.state == State.FINISHED, engine.progress.faults
    return uid
