"""The `station` command: run procedures on a station (the simulated one by default), identify,
import/export sessions, gap diagnosis."""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import re
import shlex
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import zmq
from tqdm import tqdm

from drivers.config import ConfigError
from drivers.errors import DriverError
from procedures.common.references import REFERENCES_FILE
from procedures.common.session_certificate import session_uid
from procedures.integral_precession.budget import identify_with_budget
from procedures.integral_precession.identify import METHODS, state_first_passage_bias
from station.central.cli import SyncAfterRun, add_serve_options, add_sync_command
from station.cli.console import (
    DEFAULT_PROCEDURE,
    confirmed,
    controller_for,
    describe_plan,
    exit_code,
    load_station,
    open_station,
    run_with_progress,
    write_outputs,
)
from station.cli.control import ControlServer
from station.cli.controller import RESUMABLE
from station.cli.panel import add_commands as add_panel_commands
from station.cli.signals import RunSignals
from station.control_channel import TOKEN_FILE, ControlError, ensure_token
from station.defaults import shipped_file
from station.engine.context import ValidationError
from station.engine.params import ParameterError
from station.engine.planning import checked_plan, plan_procedure
from station.engine.registry import (
    ProcedureError,
    ProcedureSpec,
    get_procedure,
    load_library,
    load_procedure_file,
    procedure_file_serial,
)
from station.errors import StationError
from station.extras import MissingExtra, needs_extra
from station.interchange import SessionFormatError, SessionWriter, content_hash, read_session, write_session
from station.jsonsafe import json_safe
from station.least_squares import FitError
from station.provenance import make_provenance
from station.session import Session
from station.session_lock import recover_interrupted
from station.store import SessionStore, StoreError
from station.telemetry import ensure_telemetry_keys
from station.twin.config import TwinConfig, TwinConfigError, default_twin
from station.twin.plan import seed000_plan
from station.twin.session_sim import simulate_points, station_info

T = TypeVar("T")


def positive_float(text: str) -> float:
    """argparse type of --speed: a finite number > 0 (0 would stop the simulated station's clock)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number; allowed: a number > 0, e.g. 1000") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text} is not allowed: station seconds per wall second must be a finite "
                                         "number > 0, e.g. 1 (real time) or 1000")  # fmt: skip
    return value


def _pace(speed: float | None) -> str:
    return "as fast as the CPU allows" if speed is None else f"at most {speed:g}x real time"


ENDPOINT = re.compile(r"^(tcp://([^:/\s\[\]]+|\[[0-9A-Fa-f:.]+\]):(\d{1,5}|\*)|ipc://\S+|inproc://\S+)$")


def zmq_endpoint(text: str) -> str:
    """argparse type of --control and --telemetry: a zmq endpoint tcp://HOST:PORT, ipc://PATH or inproc://NAME."""
    if not ENDPOINT.match(text):
        raise argparse.ArgumentTypeError(f"{text!r} is not an endpoint: allowed tcp://HOST:PORT (e.g. "
                                         "tcp://127.0.0.1:5561), ipc://PATH or inproc://NAME")  # fmt: skip
    return text


def existing_store(path: str | Path) -> Path:
    """The path of a store that must already exist (sessions, export): a missing one is an error, not a new file."""
    path = Path(path)
    if not path.is_file():
        raise StoreError(f"--db {path}: no session store there (a store is made by `station run`, `calibrate`, "
                         "`serve` or `import`; pass --db FILE)")  # fmt: skip
    return path


def _load_twin(value: str | None) -> TwinConfig:
    """The twin of --twin, a path or a shipped twin's name (the embedded default twin without one)."""
    return TwinConfig.from_toml(shipped_file(value, "twins", "--twin")) if value else default_twin()


def _run(
    args: argparse.Namespace, spec: ProcedureSpec, params: dict, resume_uid: str | None = None, serial: str = ""
) -> int:
    """Plan (dry run) before anything moves, run on the station of --station (simulated or real), then
    analyse, report and export."""
    config = load_station(args.station)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    twin = _load_twin(args.twin)  # a bad --twin is refused by the dry run too
    planner = checked_plan if resume_uid is None else plan_procedure  # a new design is checked before anything opens
    plan = planner(spec, params, config.station_model())
    if args.dry_run:
        describe_plan(plan, sys.stdout)
        return 0
    if resume_uid is None and not confirmed(plan, args.yes, sys.stderr):  # a resumed session was started already
        return 2
    if resume_uid is None:  # before anything opens: a real station does not start without the instrument's serial
        given = args.serial or serial
        make_provenance(station_id=config.station_id, simulated=config.simulated, instrument_serial=given)
    with SessionStore(args.db or out / "station.sqlite") as store:
        kind = f"simulated, seed {args.seed}, {_pace(args.speed)}" if config.simulated else "real"
        print(f"station: {config.path} ({kind}); store: {store.path}")
        with (
            open_station(config, twin, seed=args.seed, speed=args.speed) as hw,
            controller_for(config, hw, store, out, args.telemetry) as controller,
            RunSignals(controller),  # Ctrl-C pauses and asks, a second one aborts; SIGTERM aborts
        ):
            if resume_uid is None:  # a resumed session keeps the provenance it was started with
                controller.engine.operator, controller.engine.customer = args.operator, args.customer
            outcome = run_with_progress(
                controller, spec.name, params, instrument_serial=args.serial or serial, resume_uid=resume_uid
            )
        write_outputs(store, outcome, out, sys.stdout)
        if str(outcome.state) in RESUMABLE:
            print(f"resume with: {resume_command(args, outcome.session_uid)}", flush=True)
    return exit_code(outcome)


def resume_command(args: argparse.Namespace, uid: str) -> str:
    """The `station resume` command that continues session `uid` with this run's station, store and twin."""
    words = ["station", "resume", uid]
    for option, value, default in (("--station", args.station, None), ("--out", args.out, "out"),
                                   ("--db", args.db, None), ("--twin", args.twin, None), ("--seed", args.seed, 0),
                                   ("--speed", args.speed, None)):  # fmt: skip
        if value is not None and value != default:
            words += [option, shlex.quote(str(value))]
    return " ".join(words)


def cmd_calibrate(args: argparse.Namespace) -> int:
    """The main job: seed 000's session through engine, drivers and emulators; stored, identified, reported."""
    path = shipped_file(args.procedure, "procedures", "--procedure")
    return _run(args, *load_procedure_file(path), serial=procedure_file_serial(path))


def cmd_run(args: argparse.Namespace) -> int:
    path = shipped_file(args.procedure_file, "procedures", "procedure_file")
    return _run(args, *load_procedure_file(path), serial=procedure_file_serial(path))


def cmd_resume(args: argparse.Namespace) -> int:
    """Continue a crashed or aborted session: the points it holds are kept, the rest measured."""
    with SessionStore(args.db or Path(args.out) / "station.sqlite") as store:
        cfg = store.session_config(args.uid)
    if "procedure" not in cfg:
        raise ControlError(f"session {args.uid} was not started by the engine: nothing to resume")
    spec = get_procedure(cfg["procedure"])
    return _run(args, spec, spec.validate(cfg["params"]), resume_uid=args.uid)


DEFAULT_TELEMETRY = "tcp://127.0.0.1:5561"


def cmd_serve(args: argparse.Namespace) -> int:
    """Keep a station under remote control (the web panel): control channel and telemetry until SIGINT/SIGTERM."""
    config = load_station(args.station)
    if args.sync_to:  # a missing [fleet] extra is refused before anything is opened or made
        import station.central.sync  # noqa: F401
    token = os.environ.get(args.token_env) if args.token_env else None
    if args.token_env and not token:
        raise ControlError(f"--token-env {args.token_env}: that environment variable is not set")
    telemetry = args.telemetry or DEFAULT_TELEMETRY
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    keys = ensure_telemetry_keys(out / "telemetry-keys")  # CURVE for telemetry and control; before the token, which
    token_file = out / TOKEN_FILE  # tells a waiting panel that the station is there
    if token is None:  # authenticated by default: a token made on first start, readable by this user only
        token = ensure_token(token_file)
    stopped: queue.SimpleQueue[int] = queue.SimpleQueue()  # reentrant put: an Event's lock may be held by the wait
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _: stopped.put(signum))
    with (
        SessionStore(args.db or out / "station.sqlite") as store,
        open_station(config, _load_twin(args.twin), seed=args.seed, speed=args.speed) as hw,
        controller_for(config, hw, store, out, telemetry, args.name, keys) as controller,
    ):
        if args.sync_to:  # each session to the central history once it has ended and its analysis is stored
            controller.after_run.append(SyncAfterRun(store, args.sync_to, args.sync_arrays, args.name))
        server = ControlServer(controller, args.control, token=token, keys_dir=keys).start()
        auth = f"token from ${args.token_env}" if args.token_env else f"token in {token_file}"
        print(f"station {args.name} ({config.path}): control {server.endpoint} ({auth}), telemetry {telemetry}, "
              f"store {store.path}", flush=True)  # fmt: skip
        try:
            stopped.get()
        finally:
            if controller.busy:
                controller.abort()
                controller.wait(timeout_s=30.0)
            server.close()
    return 0


def cmd_identify(args: argparse.Namespace) -> int:
    """The identification with its GUM budget, by the procedure analysis' own path (identify_with_budget)."""
    session = read_session(args.session_dir)
    identified = identify_with_budget(session, args.method)
    if args.method == "baseline":  # its first-passage bias beside it, as in the procedure's analysis
        state_first_passage_bias(identified, identify_with_budget(session, "integral"))
    result = identified.to_json()
    result["references"] = {"file": str(REFERENCES_FILE), "is": "the shipped default references (Type B inputs of "
                            "the budget, config/instruments/references.toml)"}  # fmt: skip
    text = json.dumps(json_safe(result), indent=2)
    if args.json:
        Path(args.json).write_text(text)
    else:
        print(text)
    return 0


# the procedure of a session that names none (an import of a directory without one: piga-session/1 is seed 000's)
SIMULATED_PROCEDURE = "integral_precession"


def _session_for_certificate(where: str, db: str | None) -> Session:
    """An exported piga-session/1 directory, else a uid in the store `db`."""
    if Path(where).is_dir():
        return read_session(where)
    if db is None:
        raise StoreError(f"{where}: no session directory there; for a stored session pass its uid and --db STORE")
    with SessionStore(existing_store(db)) as store:
        if where not in {s["uid"] for s in store.sessions()}:
            raise StoreError(f"{where}: no such session directory, nor a session of that uid in {db} "
                             "(`station sessions --db` lists them)")  # fmt: skip
        return store.load_session(where, with_raw=False)


def cmd_certificate(args: argparse.Namespace) -> int:
    """The certificate of a stored (imported included) or exported session, issued by its procedure's analysis as
    after `station run`: certificate-UID.html and .pdf, and certificate-UID.json with the analysis' results."""
    session = _session_for_certificate(args.session, args.db)
    named = session.meta.get("procedure")
    name = SIMULATED_PROCEDURE if named in (None, "", "imported") else str(named)
    load_library()
    spec = get_procedure(name)
    analysis = spec.analyse(session) if spec.analyse is not None else None
    if analysis is None or not any(f.startswith("certificate-") for f in analysis.files):
        why_not = [line for line in (analysis.summary if analysis else "").splitlines() if line.startswith("no certi")]
        raise ProcedureError(why_not[0] if why_not else f"procedure {name!r} issues no certificate")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    uid = session_uid(session)
    for file_name, content in analysis.files.items():
        (out / Path(file_name).name).write_bytes(content)
        print(f"certificate: {out / Path(file_name).name}")
    doc = {"session_uid": uid, "procedure": name, "results": analysis.results}
    path = out / f"certificate-{uid}.json"
    path.write_text(json.dumps(json_safe(doc), indent=2))
    print(f"certificate: {path}")
    return 0


def _no_overwrite(write: Callable[[], T], out_dir: str) -> T:
    """`write()`, but an existing OUT_DIR is refused with the console's option (the API's says overwrite=True)."""
    try:
        return write()
    except FileExistsError:
        raise FileExistsError(f"{out_dir} exists; pass --overwrite to replace it") from None


def cmd_simulate(args: argparse.Namespace) -> int:
    """The twin's seed-000 session, written point by point (raw streams into raw.h5 as they come, so memory holds
    one point's arrays), with progress on stderr."""
    cfg = _load_twin(args.twin)
    plan = seed000_plan()
    writer = _no_overwrite(lambda: SessionWriter(args.out_dir, overwrite=args.overwrite), args.out_dir)
    try:
        tty = sys.stderr.isatty()  # a log gets one line per tenth, not a carriage-return bar
        with tqdm(total=len(plan), unit="point", file=sys.stderr, desc="simulate", mininterval=1.0,
                  disable=not tty) as bar:  # fmt: skip
            for i, sp in enumerate(simulate_points(plan, cfg, args.seed, raw=args.raw), 1):
                writer.add_point(sp.record, sp.raw)
                bar.update()
                if not tty and (10 * i) // len(plan) > (10 * (i - 1)) // len(plan):
                    print(f"simulate: {i}/{len(plan)} points", file=sys.stderr, flush=True)
    except BaseException:
        writer.abort()
        raise
    prov = make_provenance(station_id="twin", simulated=True, seed=args.seed)
    writer.finish(Session(station_info(cfg), [], notes="simulated seed-000 session", provenance=prov))
    print(f"wrote {len(plan)} points to {args.out_dir}")
    return 0


def cmd_sessions(args: argparse.Namespace) -> int:
    with SessionStore(existing_store(args.db)) as store:
        recover_interrupted(store)  # running with no live process: interrupted (resumable, reportable)
        sessions = store.sessions()
        if sessions:
            print(f"{'uid':{len(sessions[0]['uid'])}s}  {'created (UTC)':{len(sessions[0]['created_utc'])}s}  "
                  f"{'procedure':32s} {'status':9s} {'points':>11s} {'measurements':>17s}")  # fmt: skip
        else:
            print(f"no sessions in {store.path}")
        for s in sessions:
            print(f"{s['uid']}  {s['created_utc']}  {s['procedure']:32s} {s['status']:9s} {s['n_points']:4d} points"
                  f" {s['n_measurements']:4d} measurements")  # fmt: skip
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    with SessionStore(existing_store(args.db)) as store:
        session = store.load_session(args.uid)
    _no_overwrite(lambda: write_session(session, args.out_dir, overwrite=args.overwrite), args.out_dir)
    print(f"exported {args.uid} to {args.out_dir}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    """Validate the whole directory, then store it in one transaction; the same content twice is one session."""
    session = read_session(args.session_dir)
    with SessionStore(args.db) as store:
        uid, created = store.import_session(session, content_hash(session))
    if not created:
        print(f"already imported: the same content is session {uid} (nothing stored)")
        return 0
    print(f"imported {len(session.points)} points and {len(session.measurements)} measurements as session {uid}")
    return 0


_OWN_PARSERS = ("gap", "gap-validate")


def _passed_on(rest: list[str]) -> list[str]:
    """The arguments of a command that parses its own (main puts a "--" in front of them)."""
    return rest[1:] if rest[:1] == ["--"] else rest


def cmd_gap(args: argparse.Namespace) -> int:
    from station.gap.api import main as gap_main

    return gap_main(_passed_on(args.rest))


def cmd_gap_validate(args: argparse.Namespace) -> int:
    from station.gap.validate import main as validate_main

    return validate_main(_passed_on(args.rest))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="station", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    def station_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--station", help="station configuration TOML, or a shipped station's name (tumble-sim: "
                       "config/stations/tumble-sim.toml) (default: vibration-sim)")  # fmt: skip
        p.add_argument("--out", default="out", help="directory for the store, reports and exports (default: out)")
        p.add_argument("--db", help="SQLite session store (default: OUT/station.sqlite)")
        p.add_argument("--twin", help="twin configuration TOML of a simulated station, or a shipped twin's name "
                       "(multiposition: config/twins/multiposition.toml) (default: embedded)")  # fmt: skip
        p.add_argument("--seed", type=int, default=0, help="random seed of a simulated station")
        p.add_argument(
            "--speed",
            type=positive_float,
            help="at most this many simulated station seconds per wall second, > 0, for watching a run live "
            "(default: as fast as the CPU allows; ignored by a real station)",
        )
        p.add_argument(
            "--serial",
            help="instrument serial number (default: the procedure file's instrument_serial; "
            "required on a real station, SIM-PIGA-0001 on a simulated one)",
        )
        p.add_argument("--telemetry", metavar="ENDPOINT", type=zmq_endpoint,
                       help="publish telemetry on this zmq endpoint (tcp://HOST:PORT)")  # fmt: skip
        p.add_argument("--dry-run", action="store_true", help="validate and print the time estimates; move nothing")

    def session_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--operator", help="who runs the session, as its provenance and certificate name them "
                       "(default: the user at the console)")  # fmt: skip
        p.add_argument("--customer", help="the customer whose instrument is calibrated, named on the certificate "
                       "(required for a real station's certificate)")  # fmt: skip

    p = sub.add_parser("calibrate", help="the main job: seed 000's calibration session on the simulated station")
    station_options(p)
    session_options(p)
    p.add_argument("--yes", action="store_true", help="run a design that the dry run warns about")
    p.add_argument("--procedure", default=str(DEFAULT_PROCEDURE),
                   help="procedure file, or a shipped one's name (default: integral_precession, seed 000)")  # fmt: skip
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("run", help="run a procedure file on a station")
    p.add_argument("procedure_file", help="procedure TOML (`procedure = NAME` and [params]), or a shipped one's "
                   "name: its file name under config/procedures without .toml (every procedure has one of its own "
                   "name, e.g. integral_precession; others too, e.g. rlg_g_sensitivity-quick)")  # fmt: skip
    station_options(p)
    session_options(p)
    p.add_argument("--yes", action="store_true", help="run a design that the dry run warns about")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("resume", help="continue a crashed or aborted session")
    p.add_argument("uid", help="the session's uid (`station sessions` lists them)")
    station_options(p)
    p.set_defaults(func=cmd_resume)

    p = sub.add_parser("serve", help="keep a station under remote control (for the web panel)")
    station_options(p)
    p.add_argument("--name", default="station", help="station id in telemetry topics (default: station)")
    p.add_argument("--control", default="tcp://127.0.0.1:5560", type=zmq_endpoint,
                   help="control endpoint (zmq REP) to bind (default tcp://127.0.0.1:5560)")  # fmt: skip
    p.add_argument("--token-env", metavar="VAR", help="require the control token held in this environment variable")
    add_serve_options(p)  # --sync-to URL --sync-arrays DIR
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("identify", help="identify coefficients from a piga-session/1 directory")
    p.add_argument("session_dir", help="a piga-session/1 directory (session.json, points.csv, ...)")
    p.add_argument("--json", help="write the result here instead of standard output")
    p.add_argument("--method", choices=METHODS, default="integral",
                   help="integral: integral precession with exact window means (default); baseline: the integer "
                   "periodic vibration model of seed 000 eq. 35 (no kz)")  # fmt: skip
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("certificate", help="issue the certificate of an exported or stored (imported) session")
    p.add_argument("session", metavar="SESSION_DIR_OR_UID", help="a piga-session/1 directory, or a session's uid "
                   "in the store of --db")  # fmt: skip
    p.add_argument("--db", help="the store of a session given by its uid (`station sessions --db` lists them)")
    p.add_argument("--out", default="out", help="directory for certificate-UID.html, .pdf and .json; a directory "
                   "never stored is named by its content, UID sha256-<16 hex digits> (default: out)")  # fmt: skip
    p.set_defaults(func=cmd_certificate)

    p = sub.add_parser(
        "simulate", help="write a seed-000 session by the session_sim shortcut (not the engine) as piga-session/1"
    )
    p.add_argument("out_dir", help="the piga-session/1 directory to write")
    p.add_argument("--twin", help="twin configuration TOML, or a shipped twin's name (default: embedded, "
                   "station/twin/data/default_twin.toml)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="random seed: the same seed gives the same session (default 0)")
    p.add_argument("--raw", action="store_true", help="also write the raw streams (grating, pulse edges, references)")
    p.add_argument("--overwrite", action="store_true", help="replace OUT_DIR if it exists")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("sessions", help="list the sessions in a store")
    p.add_argument("--db", default="out/station.sqlite", help="the store (default: out/station.sqlite)")
    p.set_defaults(func=cmd_sessions)

    p = sub.add_parser("export", help="export a stored session as piga-session/1")
    p.add_argument("uid", help="the session's uid (`station sessions` lists them)")
    p.add_argument("out_dir", help="the piga-session/1 directory to write")
    p.add_argument("--db", default="out/station.sqlite", help="the store (default: out/station.sqlite)")
    p.add_argument("--overwrite", action="store_true", help="replace OUT_DIR if it exists")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("import", help="import a piga-session/1 directory into a store")
    p.add_argument("session_dir", help="a piga-session/1 directory, validated whole before anything is stored")
    p.add_argument("--db", default="out/station.sqlite", help="the store, made if missing (default out/station.sqlite)")
    p.set_defaults(func=cmd_import)

    for name, func, text in (
        ("gap", cmd_gap, "sim-to-real gap diagnosis of a session"),
        ("gap-validate", cmd_gap_validate, "blind validation of the gap diagnosis"),
    ):
        p = sub.add_parser(name, help=text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(func=func)
    add_sync_command(sub)
    add_panel_commands(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] and argv[0] in _OWN_PARSERS:
        argv = [argv[0], "--", *argv[1:]]  # argparse.REMAINDER alone would refuse a leading option
    args = build_parser().parse_args(argv)
    try:
        with needs_extra(f"station {args.command}"):
            return args.func(args)
    except MissingExtra as exc:  # the [fleet], [web] or [notebook] part of the install is not there
        print(exc, file=sys.stderr)
        return 2
    except (
        SessionFormatError, TwinConfigError, FitError, StoreError, FileExistsError, ConfigError, ProcedureError,
        ParameterError, ValidationError, ControlError, DriverError, StationError, ValueError,
    ) as exc:  # fmt: skip
        print(f"station {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a path that cannot be read or written: name it and say why
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"station {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except zmq.ZMQError as exc:  # --control / --telemetry endpoints
        print(f"station {args.command}: error: {exc} (an endpoint is tcp://HOST:PORT, ipc://PATH or inproc://NAME,"
              f" and its port must be free)", file=sys.stderr)  # fmt: skip
        return 2
    except KeyboardInterrupt:  # Ctrl-C before a run started or after it ended: nothing is moving
        print(f"station {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
