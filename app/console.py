"""Running procedures from the console: open the station, dry run, run with a progress bar, results.

The same path serves a real station and the simulated one: the station
configuration says which (`simulated = true` starts the emulators on a
VirtualClock and opens the very same drivers on them).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

from tqdm import tqdm

from app.controller import RunOutcome, StationController
from devices.config import StationConfig, load_station_config
from devices.station import StationDevices, simulated_station
from engine.planning import Plan
from engine.protocols import StationHardware
from engine.runner import State
from models.config import TwinConfig
from station.interchange import write_session
from station.store import SessionStore
from station.telemetry import TelemetryPublisher

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"
DEFAULT_SIM_STATION = CONFIG_DIR / "station-sim.toml"
DEFAULT_PROCEDURE = CONFIG_DIR / "procedures" / "seed000_integral.toml"
DEFAULT_SPEED = 1000.0  # simulated station time per wall second


@contextmanager
def open_station(
    config: StationConfig, twin: TwinConfig, *, seed: int = 0, speed: float = DEFAULT_SPEED
) -> Iterator[StationHardware]:
    """The station's devices (its emulators first, when the configuration is simulated); closed on exit."""
    if config.simulated:
        sim = simulated_station(config, twin, seed=seed, speed=speed)
        try:
            yield sim.devices
        finally:
            sim.close()
    else:
        devices = StationDevices.open(config)
        try:
            yield devices
        finally:
            devices.close()


def load_station(path: str | Path | None) -> StationConfig:
    return load_station_config(path or DEFAULT_SIM_STATION)


def describe_plan(plan: Plan, out: TextIO) -> None:
    """The dry run: every measurement with its time estimate, and the total."""
    est = plan.key_estimates_s()
    print(
        f"dry run of {plan.procedure}: {len(est)} measurements, {plan.total_s / 3600:.2f} h of station time", file=out
    )
    for key, s in est.items():
        print(f"  {key:28s} {s:9.1f} s", file=out)


def watch(controller: StationController, plan: Plan, out: TextIO) -> RunOutcome:
    """A progress bar over the plan's station time, with ETA, until the run ends."""
    total = max(plan.total_s, 1.0)
    bar = tqdm(total=round(total), unit="s", file=out, dynamic_ncols=True, mininterval=0.2,
               bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} station-s [{elapsed}<{remaining}{postfix}]")  # fmt: skip
    with bar:
        while (outcome := controller.wait(0.2)) is None:
            st = controller.status()
            bar.n = round(st["fraction"] * total)
            bar.set_postfix_str(f"{st['state']} {st['key']} {st['done']}/{st['total']}", refresh=False)
            bar.refresh()
        bar.n = round(controller.status()["fraction"] * total)
    return outcome


def run_with_progress(
    controller: StationController,
    procedure: str,
    params: dict,
    *,
    instrument_serial: str = "",
    resume_uid: str | None = None,
    out: TextIO | None = None,
) -> RunOutcome:
    out = out or sys.stdout
    if resume_uid:
        uid, plan = controller.resume_session(resume_uid)
    else:
        uid, plan = controller.start(procedure, params, instrument_serial=instrument_serial)
    print(f"session {uid}: {procedure}, {len(plan.measurements)} measurements, "
          f"estimated {plan.total_s / 3600:.2f} h of station time", file=out)  # fmt: skip
    t0 = time.perf_counter()
    outcome = watch(controller, plan, out)
    station_h = controller.engine.progress.elapsed_s / 3600
    print(f"{outcome.state}: {station_h:.2f} h of station time in {time.perf_counter() - t0:.1f} s of wall time",
          file=out)  # fmt: skip
    for fault in outcome.faults:
        print(f"  fault: {fault}", file=out)
    return outcome


def write_outputs(store: SessionStore, outcome: RunOutcome, out_dir: Path, out: TextIO) -> None:
    """Print the analysis, write its JSON, export the session as piga-session/1."""
    if outcome.analysis is not None:
        print(outcome.analysis.summary, file=out)
        result = out_dir / f"result-{outcome.session_uid}.json"
        result.write_text(json.dumps(outcome.analysis.results, indent=2))
        print(f"report: {outcome.report_path}\nresult: {result}", file=out)
    export = out_dir / f"session-{outcome.session_uid}"
    write_session(store.load_session(outcome.session_uid), export, overwrite=True)
    print(f"piga-session/1: {export}", file=out)


def exit_code(outcome: RunOutcome) -> int:
    """0 for a finished run whose analysis (if any) succeeded, 1 otherwise."""
    return 0 if outcome.state == State.FINISHED and not outcome.faults else 1


@contextmanager
def controller_for(
    config: StationConfig,
    hardware: StationHardware,
    store: SessionStore,
    out_dir: Path,
    telemetry: str | None = None,
    station_id: str = "station",
) -> Iterator[StationController]:
    pub = TelemetryPublisher(telemetry, station_id, hardware.clock) if telemetry else None
    controller = StationController(hardware, store, config.station_model(), reports_dir=out_dir,
                                   publish=pub.publish if pub else None)  # fmt: skip
    beacon = controller.beacon() if pub else None
    try:
        yield controller
    finally:
        if beacon is not None:
            beacon.set()
        if pub is not None:
            pub.close()
