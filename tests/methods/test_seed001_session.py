"""Seed 001 on the simulated tumble station: planning refuses what the station must not do, a session runs through
the engine, the real drivers and their emulators, and its estimates recover the twin's coefficients within their
stated uncertainties; a chamber fault ends the run with a typed error.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.config import load_station_config
from drivers.station import simulated_station
from drivers.temperature_chamber.emulator import ChamberFault
from drivers.voltmeter.emulator import accelerometer
from procedures.tumble.analysis import READING, SOAK
from station.cli.controller import StationController
from station.engine.context import ValidationError
from station.engine.planning import plan_procedure
from station.engine.registry import get_procedure
from station.engine.runner import State
from station.store import SessionStore
from station.twin.chamber_thermal import time_to_band_s
from station.twin.config import default_twin
from station.twin.pendulous_accelerometer import CF_NAMES, cf_coefficients

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]
CONFIG_DIR = Path(__file__).parents[2] / "config"
TUMBLE = load_station_config(CONFIG_DIR / "stations/tumble-sim.toml")
# A product that follows the chamber within a minute keeps the soaks short.
CONFIG = dataclasses.replace(
    TUMBLE, extras=TUMBLE.extras | {"temperature_chamber": dataclasses.replace(
        TUMBLE.extras["temperature_chamber"], time_constant_s=60.0)})  # fmt: skip
PROCEDURE = "tumble"
# Three temperatures and the return to T0, one forward and one back stroke: every coefficient of eqs. 4 and 6 (and
# the drift between temperatures) identifiable; about 1 h of station time.
QUICK = {"temperatures_c": [20, 45, -5, 20], "cycles": 1, "ramp_c_per_min": 5, "soak_s": 300, "dwell_s": 2,
         "nplc": 10, "samples": 4}  # fmt: skip
# A 4-sigma miss has probability 6e-5 for an honest estimate; over the ~40 comparisons below, 0.3 %.
Z_MAX = 4.0


@pytest.fixture
def station(tmp_path) -> Iterator[tuple]:
    sim = simulated_station(CONFIG, default_twin(), seed=7)
    store = SessionStore(tmp_path / "station.sqlite")
    controller = StationController(sim.devices, store, CONFIG.station_model(), reports_dir=tmp_path)
    try:
        yield sim, store, controller
    finally:
        if controller.busy:
            controller.abort()
            controller.wait(30)
        sim.close()
        store.close()


def _plan_error(params: dict, config=CONFIG) -> str:
    spec = get_procedure(PROCEDURE)
    with pytest.raises(ValidationError) as exc:
        plan_procedure(spec, spec.validate(params), config.station_model())
    return str(exc.value)


def test_planning_refuses_what_the_station_must_not_do() -> None:
    assert "setpoint_c = 90.0 is not allowed: -40 .. 80 deg C" in _plan_error({"temperatures_c": [20, 90]})
    assert "ramp_c_per_min = 8.0 is not allowed: 0 < rate <= 5 deg C/min" in _plan_error({"ramp_c_per_min": 8})
    assert "range_v = 0.2 is not allowed: a range that holds 1.49 V" in _plan_error({"range_v": 0.2})
    assert "range_v = 3.0 is not allowed: 0.2, 2, 20, 200, 1000 V" in _plan_error({"range_v": 3.0})
    bare = load_station_config(CONFIG_DIR / "stations/vibration-sim.toml")
    assert "device = 'temperature_chamber' is not allowed" in _plan_error({}, bare)


def test_dry_run_estimates_the_soaks() -> None:
    spec = get_procedure(PROCEDURE)
    plan = plan_procedure(spec, spec.validate(QUICK), CONFIG.station_model())
    est = plan.key_estimates_s()
    assert len(est) == 4 + 4 * 18
    section = CONFIG.extras["temperature_chamber"]
    for key, (start_c, to_c) in {"soak-T2": (20, 45), "soak-T3": (45, -5)}.items():
        settle_s = time_to_band_s(start_c, to_c, 5 / 60, section.time_constant_s, section.stable_band_c)
        assert settle_s > abs(to_c - start_c) / (5 / 60)  # the ramp and then the lag
        assert est[key] == pytest.approx(settle_s + QUICK["soak_s"], abs=10.0)  # plus the last head move


def test_session_recovers_the_twins_coefficients_within_their_uncertainties(station) -> None:
    sim, store, controller = station
    outcome = controller.run(PROCEDURE, QUICK)
    assert outcome.state == State.FINISHED, outcome.faults
    session = store.load_session(outcome.session_uid)
    accel = accelerometer(sim.world)
    thermal = sim.world.shared("temperature_chamber", lambda: None)
    m = accel.model
    results = outcome.analysis.results
    for block in results["eight_point"]["temperatures"]:
        # The truth at the block: eq. 1 at the product temperature it was read at and the bias at its mean time.
        t_s = np.array([r.values["t_s"] for r in session.measurements
                        if r.kind == READING and r.values["block"] == block["block"]])  # fmt: skip
        temperature_c = float(np.mean([thermal.temperature_c(t) for t in t_s]))
        truth = cf_coefficients(m, temperature_c, accel.bias_extra_g(block["t_mean_s"]))
        for name in CF_NAMES:
            c = block["coefficients"][name]
            assert abs(c["value"] - truth[name]) < Z_MAX * c["sigma"], (block["block"], name, c, truth[name])
        h = block["hysteresis_g"]
        assert abs(h["value"] - m.hysteresis_g) < Z_MAX * h["sigma"]
    laws = results["temperature_model"]
    first_t_s = results["eight_point"]["temperatures"][0]["t_mean_s"]
    expected = {
        ("bias_g", "at_reference"): m.k0_g + accel.bias_extra_g(first_t_s),
        ("bias_g", "above"): m.lambda_above_g_per_c, ("bias_g", "below"): m.lambda_below_g_per_c,
        ("bias_g", "drift_per_s"): m.drift_g_per_s,
        ("scale_factor", "above"): m.beta_above_per_c, ("scale_factor", "below"): m.beta_below_per_c,
        ("misalignment_rad", "above"): m.gamma_above_rad_per_c,
        ("misalignment_rad", "below"): m.gamma_below_rad_per_c,
    }  # fmt: skip
    for (law, term), truth in expected.items():
        c = laws[law][term]
        assert abs(c["value"] - truth) < Z_MAX * c["sigma"], (law, term, c, truth)
    soaks = {s.key: s for s in session.measurements if s.kind == SOAK}
    assert soaks["soak-T3"].values["settled_s"] > 600  # 50 C at 5 C/min, then the lag
    assert soaks["soak-T3"].arrays["temperature_c"][-1] == pytest.approx(-5.0, abs=0.1)
    report = outcome.report_path.read_text()
    assert report.count("<svg") == 3 and "Y_JK at T4 20 °C" in report and "λ" in report
    assert not any(tag in report for tag in ("<script", "<link", 'src="http', 'href="http'))  # self-contained


def test_a_chamber_fault_ends_the_run_with_a_typed_error(station) -> None:
    sim, store, controller = station
    sim.emulators["temperature_chamber"].inject(ChamberFault.SENSOR_BREAK, count=None)
    outcome = controller.run(PROCEDURE, QUICK | {"temperatures_c": [20], "cycles": 1, "soak_s": 0})
    assert outcome.state == State.FAILED
    assert any("DeviceFault: temperature chamber: alarms = 'sensor break'" in f for f in outcome.faults)
    assert store.load_session(outcome.session_uid).measurements == []
