"""Seed 000 integral-precession sessions by both simulation paths, on one design and one seed.

- `engine_session`: through the engine on the deterministic station (config/station-sim.toml: the
  discrete-event clock, the real drivers against their emulators, the calling thread the clock's party), in this
  process, nothing written but a temporary store; what `station calibrate` records, without the report.
- `shortcut_session`: the session_sim shortcut (models.session_sim, not the engine): the twin's point simulator
  called point after point with a nominal 60 s between windows.

Both take the procedure's parameters (positions_deg, freqs_hz, window_s) and give the same plan of points (ids,
positions, frequencies, preset pulses). They do not draw the same noise: the engine's crank phase at each
window's opening follows from the whole station timeline (index moves, ramps, settling, the drivers' exchanges),
the shortcut draws it uniformly; the rate-noise offsets come from different generators. Shared by
tests/test_simulation_paths.py and bench/bench_calibration_mc.py (tests/ on its path).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from devices.config import load_station_config
from devices.station import simulated_station
from engine.planning import plan_procedure
from engine.registry import load_procedure_file
from engine.runner import Engine, State
from models.config import TwinConfig, default_twin
from models.plan import multiposition_plan
from models.session_sim import simulate_session
from station.session import Session
from station.store import SessionStore

CONFIG = Path(__file__).resolve().parents[1] / "config"
PROCEDURE = CONFIG / "procedures" / "seed000_integral.toml"


def engine_session(params: dict[str, Any], seed: int, twin: TwinConfig | None = None) -> Session:
    """seed000_integral.toml with `params` over its own, through the engine on the deterministic station."""
    cfg = load_station_config(CONFIG / "station-sim.toml")
    spec, base = load_procedure_file(PROCEDURE)
    p = spec.validate(dict(base) | params)
    plan = plan_procedure(spec, p, cfg.station_model())
    with (
        tempfile.TemporaryDirectory() as tmp,
        simulated_station(cfg, twin or default_twin(), seed=seed) as sim,
        SessionStore(Path(tmp) / "s.sqlite") as store,
        sim.devices.clock.party("engine"),
    ):
        engine = Engine(sim.devices, store)
        uid, _ = engine.run(spec, plan, instrument_serial="PIGA-SIM")
        if engine.progress.state != State.FINISHED:
            raise RuntimeError(f"engine session (seed {seed}) ended {engine.progress.state}: {engine.progress.faults}")
        return store.load_session(uid, with_raw=False)


def shortcut_session(params: dict[str, Any], seed: int, twin: TwinConfig | None = None) -> Session:
    """The same design by the session_sim shortcut (not the engine)."""
    _, base = load_procedure_file(PROCEDURE)
    p = dict(base) | params
    plan = multiposition_plan(p["positions_deg"], p["freqs_hz"], p["window_s"])
    return simulate_session(plan, twin or default_twin(), seed=seed)
