"""Running procedures from the console: open the station, dry run, run with a progress bar, results.

The same path serves a real station and the simulated one: the station
configuration says which (`simulated = true` starts the emulators on a
VirtualClock and opens the very same drivers on them).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

from tqdm import tqdm

from drivers.config import StationConfig, load_station_config
from drivers.station import StationDevices, simulated_station
from procedures.common.session_certificate import measurement_duration
from station.cli.controller import RunOutcome, StationController, write_run_files
from station.coefficients import MU_NOTE, UNCERTAINTY_NOTE, coefficient_rows, conclusion, format_rows
from station.defaults import config_dir, shipped_file
from station.engine.planning import Plan
from station.engine.protocols import StationHardware
from station.engine.registry import get_procedure
from station.engine.runner import FINAL_STATES, State
from station.store import SessionStore
from station.telemetry import TelemetryPublisher
from station.twin.config import TwinConfig

CONFIG_DIR = config_dir()  # the shipped defaults (station.defaults): package data, or config/ in a source tree
DEFAULT_SIM_STATION = CONFIG_DIR / "stations/vibration-sim.toml"
DEFAULT_PROCEDURE = CONFIG_DIR / "procedures" / "integral_precession.toml"


@contextmanager
def open_station(
    config: StationConfig, twin: TwinConfig, *, seed: int = 0, speed: float | None = None
) -> Iterator[StationHardware]:
    """The station's devices (its emulators first, when the configuration is simulated); closed on exit.

    A simulated station runs on the discrete-event clock: as fast as the CPU allows, or at most `speed`
    station seconds per wall second for watching it live."""
    if config.simulated:
        sim = simulated_station(config, twin, seed=seed, speed=speed, deterministic=True)
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


def load_station(value: str | Path | None) -> StationConfig:
    """The station configuration of --station, a path or a shipped station's name (the simulated station's by
    default); a value that is neither is named as the operator typed it."""
    return load_station_config(shipped_file(value, "stations", "--station") if value else DEFAULT_SIM_STATION)


def describe_plan(plan: Plan, out: TextIO) -> None:
    """The dry run: every measurement with its time estimate, and the total."""
    est = plan.key_estimates_s()
    print(
        f"dry run of {plan.procedure}: {len(est)} measurements, {plan.total_s / 3600:.2f} h of station time", file=out
    )
    for key, s in est.items():
        print(f"  {key:28s} {s:9.1f} s", file=out)
    describe_warnings(plan, out)


def describe_warnings(plan: Plan, out: TextIO) -> None:
    """The design's warnings, each with its field, value, reason and fix."""
    for w in plan.warnings:
        print(w.line(), file=out)


def confirmed(plan: Plan, yes: bool, out: TextIO) -> bool:
    """Whether the run may start: a design with warnings needs `--yes` (the warnings are printed either way)."""
    describe_warnings(plan, out)
    if plan.warnings and not yes:
        print(f"{len(plan.warnings)} warning(s) about the design of {plan.procedure}: nothing moved; "
              "pass --yes to run it anyway", file=out)  # fmt: skip
    return yes or not plan.warnings


PLAIN_STEP = 0.1  # a log (stderr not a terminal) gets one progress line per tenth of the plan


def watch(controller: StationController, plan: Plan, err: TextIO | None = None, analysed: bool = False) -> RunOutcome:
    """Progress on stderr until the run ends: a bar with ETA over the plan's station time on a terminal,
    one line per tenth in a log; then the analysis-and-report stage, timed, until the outcome is there."""
    err = err or sys.stderr
    total = max(plan.total_s, 1.0)
    tty = err.isatty()
    bar = tqdm(total=round(total), unit="s", file=err, dynamic_ncols=True, mininterval=0.2, disable=not tty,
               bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} station-s [{elapsed}<{remaining}{postfix}]")  # fmt: skip
    next_line = PLAIN_STEP
    with bar:
        while (outcome := controller.wait(timeout_s=0.2)) is None:
            st = controller.status()
            if st["state"] in FINAL_STATES:
                break  # measuring is over; the analysis runs in its child process
            bar.n = round(st["fraction"] * total)
            bar.set_postfix_str(f"{st['state']} {st['key']} {st['done']}/{st['total']}", refresh=False)
            bar.refresh()
            if not tty and st["fraction"] >= next_line:
                print(f"progress: {100 * st['fraction']:.0f} % of {total / 3600:.2f} h of station time, "
                      f"{st['done']}/{st['total']} measurements, at {st['key']}", file=err, flush=True)  # fmt: skip
                next_line = math.floor(st["fraction"] / PLAIN_STEP + 1) * PLAIN_STEP
        bar.n = round(controller.status()["fraction"] * total)
    if outcome is None:
        st = controller.status()
        print(f"measuring {st['state']}: {st['done']}/{st['total']} measurements", file=err, flush=True)
        t0 = time.perf_counter()
        if st["state"] == State.FINISHED and analysed:
            print("analysis and report: fitting and writing the HTML report (in a child process) ...", file=err,
                  flush=True)  # fmt: skip
        while (outcome := controller.wait(timeout_s=1.0)) is None:
            if tty:
                print(f"\ranalysis and report: {time.perf_counter() - t0:.0f} s", end="", file=err, flush=True)
        if outcome.analysis is not None:
            print(f"{chr(13) if tty else ''}analysis and report: done in {time.perf_counter() - t0:.1f} s of wall "
                  "time", file=err, flush=True)  # fmt: skip
    return outcome


def run_with_progress(
    controller: StationController,
    procedure: str,
    params: dict,
    *,
    instrument_serial: str = "",
    resume_uid: str | None = None,
    out: TextIO | None = None,
    err: TextIO | None = None,
) -> RunOutcome:
    """Start (or resume) the run and watch it: facts on `out` (stdout), progress and stages on `err` (stderr)."""
    out = out or sys.stdout
    if resume_uid:
        uid, plan = controller.resume_session(resume_uid)
    else:
        uid, plan = controller.start(procedure, params, instrument_serial=instrument_serial)
    print(f"session {uid}: {procedure}, {len(plan.measurements)} measurements, "
          f"estimated {plan.total_s / 3600:.2f} h of station time", file=out)  # fmt: skip
    t0 = time.perf_counter()
    outcome = watch(controller, plan, err, analysed=get_procedure(procedure).analyse is not None)
    measured = measurement_duration(controller.engine.store.load_session(uid, with_raw=False))  # the certificate's
    print(f"{outcome.state}: {measured} in {time.perf_counter() - t0:.1f} s of wall time", file=out)
    for fault in outcome.faults:
        print(f"  fault: {fault}", file=out)
    return outcome


def write_outputs(store: SessionStore, outcome: RunOutcome, out_dir: Path, out: TextIO) -> None:
    """Print the analysis and where its JSON and the session's piga-session/1 export are (the controller wrote
    them; written here for a run whose worker was lost)."""
    if outcome.export_path is None:
        write_run_files(store, outcome, out_dir)
    if outcome.analysis is not None:
        print(describe_results(outcome.analysis.results, outcome.analysis.summary), file=out)
        print(f"report: {outcome.report_path}\nresult: {outcome.result_path}", file=out)
        if outcome.report_path is not None:  # the analysis job writes the certificate beside the report
            for path in sorted(Path(outcome.report_path).parent.glob(f"certificate-{outcome.session_uid}.*")):
                print(f"certificate: {path}", file=out)
    print(f"piga-session/1: {outcome.export_path}", file=out)
    results = outcome.analysis.results if outcome.analysis is not None else None
    for line in conclusion(str(outcome.state), results, outcome.faults, outcome.report_path is not None):
        print(line, file=out)


def describe_results(results: dict, summary: str) -> str:
    """The coefficients with their units, u and U = k u, each fit's residual sigma and mu vs mu_c, and what
    the uncertainty means; then the method's own summary (what to do next: a mass to remove, ...) but for its
    lines on the results already listed."""
    lines: list[str] = []
    rows = coefficient_rows(results)
    for name in dict.fromkeys(r.result for r in rows):
        doc = results.get(name, {}) if isinstance(results.get(name), dict) else {}
        head = f"{name}:"
        if doc.get("n_points") is not None:
            head += f" {doc['n_points']} points, {doc.get('dof', '?')} degrees of freedom"
        lines.append(head)
        lines += format_rows([r for r in rows if r.result == name])
        if isinstance(doc.get("sigma_residual"), float):
            unit = doc.get("units", {}).get("sigma_residual", "")
            lines.append(f"  residual sigma = {doc['sigma_residual']:.3e} {unit}".rstrip())
        if doc.get("mu") is not None and doc.get("mu_c") is not None:
            lines.append(f"  mu = {doc['mu']:.2f}, mu_c = {doc['mu_c']:.2f} (dimensionless)")
    shown = {r.result for r in rows}
    # the method's own summary, but for its lines on the results listed above ("integral: kz = ...")
    lines += [line for line in summary.splitlines() if line.split(":", 1)[0].strip() not in shown]
    if rows:
        lines.append(f"({UNCERTAINTY_NOTE}; {MU_NOTE})")
    return "\n".join(lines)


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
    telemetry_keys: Path | None = None,
) -> Iterator[StationController]:
    """The controller of a station, publishing telemetry on `telemetry` (CURVE-encrypted for the holders of
    `telemetry_keys`' allowed keys only, when given) with its status beacon; closed on exit."""
    pub = TelemetryPublisher(telemetry, station_id, hardware.clock, keys_dir=telemetry_keys) if telemetry else None
    controller = StationController(hardware, store, config.station_model(), reports_dir=out_dir,
                                   publish=pub.publish if pub else None)  # fmt: skip
    beacon = controller.beacon() if pub else None
    try:
        yield controller
    finally:
        controller.close()  # a run still under way is aborted (bounded) before the devices close
        if beacon is not None:
            beacon.set()
        if pub is not None:
            pub.close()
