"""Seed 000 integral-precession sessions by both simulation paths, on one design and one seed.

- `engine_session`: through the engine on the deterministic station (config/stations/vibration-sim.toml: the
  discrete-event clock, the real drivers against their emulators, the calling thread the clock's party), in this
  process, nothing written but a temporary store; what `station calibrate` records, without the report.
- `shortcut_session`: the session_sim shortcut (station.twin.session_sim, not the engine): the twin's point simulator
  called point after point with a nominal 60 s between windows.

Both take the procedure's parameters (positions_deg, freqs_hz, window_s) and give the same plan of points (ids,
positions, frequencies, preset pulses). They do not draw the same noise: the engine's crank phase at each
window's opening follows from the whole station timeline (index moves, ramps, settling, the drivers' exchanges),
the shortcut draws it uniformly; the rate-noise offsets come from different generators. Shared by
tests/test_simulation_paths.py and bench/bench_calibration_mc.py (tests/ on its path).

Seed 001 tumble sessions the same two ways (tests/test_simulation_paths_seed001.py):

- `engine_tumble_session`: tumble.toml through the engine on config/stations/tumble-sim.toml (the voltmeter
  reading the world's TumbledAccelerometer at the head's angle and the chamber's product temperature), with the
  true eq. 1 coefficients of each temperature block: the accelerometer's model at the mean product temperature of
  the block's readings, its launch offset and drift at their mean time (what procedures.tumble.tumble_session
  returns for its own sessions).
- `shortcut_tumble_session`: procedures.tumble.tumble_session (not the engine) at the same temperatures and cycles,
  a reading's noise `tumble_reading_sigma_g` (what the emulators add for the procedure's nplc, samples and range).

Same plan of readings (names, blocks, positions, strokes, the head's path); not the same draws: the shortcut takes
the launch offset and the reading noise from one generator in its own order, the station from the world's
generators; the shortcut's timeline is a fixed hour of soak and 20 s a reading, the station's follows the
chamber's ramp and settling and the head's moves.

Seed 002 calibration runs the same two ways (tests/test_simulation_paths_seed002.py):

- `engine_vibration_runs`: rlg_g_sensitivity.toml through the engine on config/stations/shaker-sim.toml (the
  simulated operator mounting each pose, the IMU's emulator streaming quantised increments over its line), the
  stored values of each calibration run (A, B of eqs. 17-22) with the IMU's twin and the site;
- `shortcut_vibration_runs`: each pose's run made off line by procedures.rlg_g_sensitivity.vibration_run (not the
engine)
  and reduced by procedures.rlg_g_sensitivity.analysis.observe_run, as bench/bench_seed002.py's table2 does.

Same poses, drives and lengths; not the same draws (mount errors and sensor noise from different generators).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from drivers.config import load_station_config
from drivers.shaker.envelope import G_STANDARD_MPS2
from drivers.station import simulated_station
from drivers.temperature_chamber.emulator import ChamberThermal
from drivers.voltmeter.emulator import METER_NOISE_OF_RANGE, accelerometer
from procedures.rlg_g_sensitivity.analysis import RunRecord, observation_values, observe_run
from procedures.rlg_g_sensitivity.vibration_run import simulate_run
from procedures.tumble.tumble_session import tumble_session
from station.engine.planning import plan_procedure
from station.engine.registry import load_procedure_file
from station.engine.runner import Engine, State
from station.session import Session
from station.store import SessionStore
from station.twin.config import TwinConfig, default_twin
from station.twin.fixture_poses import POSES
from station.twin.pendulous_accelerometer import AccelerometerModel, cf_coefficients, noise_sigma_g
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session
from station.twin.shaker_motion import sine_drive
from station.twin.strapdown_imu import Site, StrapdownImuTwin

CONFIG = Path(__file__).resolve().parents[1] / "config"
PROCEDURE = CONFIG / "procedures" / "integral_precession.toml"
TUMBLE_STATION = CONFIG / "stations/tumble-sim.toml"
TUMBLE_PROCEDURE = CONFIG / "procedures" / "tumble.toml"
SHAKER_STATION = CONFIG / "stations/shaker-sim.toml"
SHAKER_PROCEDURE = CONFIG / "procedures" / "rlg_g_sensitivity.toml"


def chi2_ok(sum_sq: float, dof: int, level: float) -> bool:
    """sum_sq within the chi-square(dof) bounds at two-sided `level`."""
    return bool(stats.chi2.ppf(level / 2, dof) <= sum_sq <= stats.chi2.ppf(1 - level / 2, dof))


def f_ok(ratio: float, d1: int, d2: int, level: float) -> bool:
    """A variance ratio within F(d1, d2)'s bounds at two-sided `level`."""
    return bool(stats.f.ppf(level / 2, d1, d2) <= ratio <= stats.f.ppf(1 - level / 2, d1, d2))


def assert_same_normal_scatter(samples: dict[str, np.ndarray], what: str) -> None:
    """Two paths' z (unit normal if each path holds its noise model): per path |mean| <= 4 / sqrt(n) and the
    variance within the chi-square(n - 1) bounds at two-sided 1e-4; between them the variances' ratio within F's
    bounds at two-sided 1e-3 and the means within 4 sigma of each other."""
    for path, x in samples.items():
        assert abs(x.mean()) <= 4 / math.sqrt(x.size), f"{path} {what}: mean z {x.mean():.3f} over {x.size}"
        spread = float(((x - x.mean()) ** 2).sum())
        assert chi2_ok(spread, x.size - 1, 1e-4), f"{path} {what}: z sd {x.std(ddof=1):.3f} over {x.size}"
    (pa, a), (pb, b) = samples.items()
    va, vb = a.var(ddof=1), b.var(ddof=1)
    assert f_ok(va / vb, a.size - 1, b.size - 1, 1e-3), f"{what}: z variance {pa} / {pb} {va / vb:.3f}"
    assert abs(a.mean() - b.mean()) <= 4 * math.sqrt(va / a.size + vb / b.size), (
        f"{what}: mean z {pa} {a.mean():.3f}, {pb} {b.mean():.3f}"
    )


def _engine_run(
    station: Path, procedure: Path, params: dict[str, Any], seed: int, twin: TwinConfig | None, look: Any = None
) -> tuple[Session, Any]:
    """The procedure file with `params` over its own through the engine on the deterministic station `station`:
    (the stored session, look(sim, session) while the station is still up, None without `look`)."""
    cfg = load_station_config(station)
    spec, base = load_procedure_file(procedure)
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
        session = store.load_session(uid, with_raw=False)
        return session, None if look is None else look(sim, session)


def engine_session(params: dict[str, Any], seed: int, twin: TwinConfig | None = None) -> Session:
    """integral_precession.toml with `params` over its own, through the engine on the deterministic station."""
    return _engine_run(CONFIG / "stations/vibration-sim.toml", PROCEDURE, params, seed, twin)[0]


def shortcut_session(params: dict[str, Any], seed: int, twin: TwinConfig | None = None) -> Session:
    """The same design by the session_sim shortcut (not the engine)."""
    _, base = load_procedure_file(PROCEDURE)
    p = dict(base) | params
    plan = multiposition_plan(p["positions_deg"], p["freqs_hz"], p["window_s"])
    return simulate_session(plan, twin or default_twin(), seed=seed)


def tumble_params(params: dict[str, Any]) -> dict[str, Any]:
    """tumble.toml's parameters with `params` over them (validated)."""
    spec, base = load_procedure_file(TUMBLE_PROCEDURE)
    return spec.validate(dict(base) | params)


def tumble_reading_sigma_g(params: dict[str, Any], m: AccelerometerModel | None = None) -> float:
    """The white noise of one tumble reading (the mean of `samples` conversions) in g, as the station's emulators
    make it: the accelerometer's noise density over the aperture nplc / line_hz, and the voltmeter's 0.15 ppm of
    range at 10 PLC (per conversion, as 1 / sqrt(nplc)) over the nominal scale factor."""
    m = m or AccelerometerModel()
    p = tumble_params(params)
    line_hz = load_station_config(TUMBLE_STATION).extras["voltmeter"].line_hz
    accel_g = noise_sigma_g(m, p["nplc"] / line_hz)
    meter_g = METER_NOISE_OF_RANGE * p["range_v"] * math.sqrt(10.0 / p["nplc"]) / m.scale_v_per_g
    return math.hypot(accel_g, meter_g) / math.sqrt(p["samples"])


def _block_truths(session: Session, model: AccelerometerModel, temperature_c: Any, bias_extra_g: Any) -> list:
    """Per temperature block: eq. 1's coefficients at the mean true temperature and the mean time of its readings."""
    readings = [m for m in session.measurements if m.kind == "tumble"]
    truths = []
    for block in sorted({m.values["block"] for m in readings}):
        t = [m.values["t_s"] for m in readings if m.values["block"] == block]
        temperature = float(np.mean([temperature_c(x) for x in t]))
        truths.append(cf_coefficients(model, temperature, bias_extra_g(float(np.mean(t)))))
    return truths


def engine_tumble_session(params: dict[str, Any], seed: int) -> tuple[Session, list[dict[str, float]]]:
    """tumble.toml with `params` over its own through the engine on the deterministic tumble station, and
    the true coefficients of each temperature block."""

    def truths(sim: Any, session: Session) -> list[dict[str, float]]:
        accel = accelerometer(sim.world)
        thermal = sim.world.shared("temperature_chamber", ChamberThermal)
        return _block_truths(session, accel.model, thermal.temperature_c, accel.bias_extra_g)

    return _engine_run(TUMBLE_STATION, TUMBLE_PROCEDURE, params, seed, None, truths)


def shortcut_tumble_session(params: dict[str, Any], seed: int) -> tuple[Session, list[dict[str, float]]]:
    """The same design by procedures.tumble.tumble_session (not the engine), the station's reading noise."""
    p = tumble_params(params)
    m = AccelerometerModel()
    sigma_g = tumble_reading_sigma_g(p, m)
    return tumble_session(m, p["temperatures_c"], p["cycles"], sigma_g, np.random.default_rng(seed))


def shaker_params(params: dict[str, Any]) -> dict[str, Any]:
    """rlg_g_sensitivity.toml's parameters with `params` over them (validated)."""
    spec, base = load_procedure_file(SHAKER_PROCEDURE)
    return spec.validate(dict(base) | params)


def _calibration_runs(session: Session) -> list[dict[str, Any]]:
    return [m.values | {"key": m.key} for m in session.measurements if m.values.get("role") == "calibration"]


def engine_vibration_runs(params: dict[str, Any], seed: int) -> tuple[list[dict[str, Any]], StrapdownImuTwin, Site]:
    """rlg_g_sensitivity.toml with `params` over its own through the engine on the deterministic shaker station:
    the stored values of its calibration runs (A, B: eqs. 17-22), the IMU's twin and the site it navigated on."""

    def twin_and_site(sim: Any, session: Session) -> tuple[StrapdownImuTwin, Site]:
        return sim.world.shared("strapdown_imu", StrapdownImuTwin), sim.emulators["imu"].site

    session, (twin, site) = _engine_run(SHAKER_STATION, SHAKER_PROCEDURE, params, seed, None, twin_and_site)
    return _calibration_runs(session), twin, site


def shortcut_vibration_runs(params: dict[str, Any], seed: int) -> list[dict[str, Any]]:
    """The same calibration runs by procedures.rlg_g_sensitivity.vibration_run (not the engine): each pose's run made
    off line
    from the IMU's twin (a new mount error, then sensor errors, from one generator), reduced by observe_run."""
    p = shaker_params(params)
    cfg = load_station_config(SHAKER_STATION)
    st = default_twin().station
    site = Site(st.g_mps2, st.earth_rate_radps, st.latitude_rad)
    rate_hz = cfg.extras["imu"].rate_hz
    rng = np.random.default_rng(seed)
    runs = []
    for i, pose in enumerate(p["poses"], 1):
        drive = sine_drive(p["freq_hz"], p["amp_g"], G_STANDARD_MPS2)
        run = simulate_run(StrapdownImuTwin(), site, POSES[int(pose)], drive, rate_hz=rate_hz, align_s=p["align_s"],
                           vibrate_s=p["vibrate_s"], ramp_s=p["ramp_s"], rng=rng)  # fmt: skip
        obs = observe_run(RunRecord.from_times(run.dtheta, run.dv, run.dt_s, 0.0, run.t0_s, run.tk_s), site)
        runs.append({"key": f"cal{i:02d}-pose{pose:g}", "role": "calibration", "pose": int(pose), "mode": "sine",
                     "level_g": p["amp_g"], "freq_hz": p["freq_hz"], "align_s": p["align_s"],
                     "vibrate_s": p["vibrate_s"], "ramp_s": p["ramp_s"], "rate_hz": rate_hz}
                    | observation_values(obs))  # fmt: skip
    return runs
