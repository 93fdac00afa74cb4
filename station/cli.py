"""The `station` command: run a simulated calibration session, identify, import/export, gap diagnosis."""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

from station.analysis.identify import METHODS, Identification, identify
from station.analysis.least_squares import FitError
from station.interchange import SessionFormatError, read_session, write_session
from station.plan import seed000_plan
from station.report import render_report
from station.store import SessionStore, StoreError
from station.twin.config import TwinConfig, TwinConfigError, default_twin
from station.twin.session_sim import simulate_points, simulate_session, station_info


def _load_twin(path: str | None) -> TwinConfig:
    return TwinConfig.from_toml(path) if path else default_twin()


def _print_identification(r: Identification, out=None) -> None:
    out = out or sys.stdout
    print(f"method: {r.method}   points: {r.n_points}   dof: {r.dof}", file=out)
    for name, v, s in zip(r.names, r.values, r.sigmas, strict=True):
        print(f"  {name:4s} = {v: .6e} ± {s:.2e}", file=out)
    verdict = "accepted" if r.mu < r.mu_c else "possible outlier (mu >= mu_c)"
    print(
        f"  sigma residual = {r.sigma_residual:.3e} rad/s;  mu = {r.mu:.3f} vs mu_c = {r.mu_c:.3f}: {verdict}", file=out
    )


def cmd_calibrate(args: argparse.Namespace) -> int:
    """The main job: the seed-000 session on the simulated station, stored, identified, reported."""
    cfg = _load_twin(args.twin)
    plan = seed000_plan()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    store = SessionStore(args.db or out / "station.sqlite")
    uid = store.create_session(
        station_info(cfg),
        "seed000_integral_precession",
        instrument_serial=args.serial,
        config={"twin": cfg.to_dict(), "seed": args.seed, "plan": [asdict(p) for p in plan]},
    )
    print(f"session {uid}: {len(plan)} points on the simulated station (seed {args.seed}); store {store.path}")
    t_wall = time.perf_counter()
    station_s = 0.0
    for i, sp in enumerate(simulate_points(plan, cfg, args.seed, raw=args.raw), start=1):
        store.add_point(uid, sp.record, sp.raw)
        p = sp.record
        station_s = p.start_s + p.Tm_s
        detail = f"Tm {p.Tm_s:.6f} s" + (f", t1 {p.t1_s:.6f}, t2 {p.t2_s:.6f}, Np {p.Np}" if p.t1_s is not None else "")
        print(f"  [{i:2d}/{len(plan)}] {p.position_deg:6.1f} deg  {p.freq_hz:4.1f} Hz  {detail}")
    store.set_status(uid, "finished")
    session = store.load_session(uid, with_raw=False)
    results = {m: identify(session, m) for m in METHODS}
    for m, r in results.items():
        store.add_result(uid, m, r.to_json())
        _print_identification(r)
    k = cfg.instrument
    truth = {"kz": k.kz, "kzz": k.kzz, "ky": k.ky, "k3": k.k3}
    report = out / f"report-{uid}.html"
    report.write_text(
        render_report(session, results, title=f"Session {uid} (simulated seed 000)", config=cfg.to_dict(), truth=truth)
    )
    result_json = out / f"result-{uid}.json"
    result_json.write_text(json.dumps({m: r.to_json() for m, r in results.items()}, indent=2))
    write_session(store.load_session(uid), out / f"session-{uid}", overwrite=True)
    print(f"{station_s / 3600:.2f} h of station time in {time.perf_counter() - t_wall:.1f} s wall")
    print(f"report: {report}\nresult: {result_json}\npiga-session/1: {out / f'session-{uid}'}")
    return 0


def cmd_identify(args: argparse.Namespace) -> int:
    session = read_session(args.session_dir)
    result = identify(session, args.method).to_json()
    text = json.dumps(result, indent=2)
    if args.json:
        Path(args.json).write_text(text)
    else:
        print(text)
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    cfg = _load_twin(args.twin)
    session = simulate_session(seed000_plan(), cfg, args.seed, raw=args.raw, notes="simulated seed-000 session")
    write_session(session, args.out_dir, overwrite=args.overwrite)
    print(f"wrote {len(session.points)} points to {args.out_dir}")
    return 0


def cmd_sessions(args: argparse.Namespace) -> int:
    with SessionStore(args.db) as store:
        for s in store.sessions():
            print(f"{s['uid']}  {s['created_utc']}  {s['procedure']:32s} {s['status']:9s} {s['n_points']:4d} points")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    with SessionStore(args.db) as store:
        write_session(store.load_session(args.uid), args.out_dir, overwrite=args.overwrite)
    print(f"exported {args.uid} to {args.out_dir}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    session = read_session(args.session_dir)  # validated whole before anything is written
    with SessionStore(args.db) as store:
        uid = store.create_session(session.station, "imported", notes=session.notes, status="imported")
        for p in session.points:
            store.add_point(uid, p, session.raw.get(p.point_id))
    print(f"imported {len(session.points)} points as session {uid}")
    return 0


def cmd_gap(args: argparse.Namespace) -> int:
    from station.gap.api import main as gap_main

    return gap_main(args.rest)


def cmd_gap_validate(args: argparse.Namespace) -> int:
    from station.gap.validate import main as validate_main

    return validate_main(args.rest)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="station", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("calibrate", help="run the seed-000 calibration session on the simulated station")
    p.add_argument("--out", default="out", help="directory for the store, report and export (default: out)")
    p.add_argument("--db", help="SQLite store (default: OUT/station.sqlite)")
    p.add_argument("--twin", help="twin configuration TOML (default: the embedded default)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the simulated station")
    p.add_argument("--serial", default="SIM-PIGA-0001", help="instrument serial number")
    p.add_argument("--raw", action="store_true", help="also record raw streams (5 kHz grating, every pulse edge)")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("identify", help="identify coefficients from a piga-session/1 directory")
    p.add_argument("session_dir")
    p.add_argument("--json", help="write the result here instead of standard output")
    p.add_argument("--method", choices=METHODS, default="integral")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("simulate", help="write a simulated seed-000 session as piga-session/1")
    p.add_argument("out_dir")
    p.add_argument("--twin")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--raw", action="store_true")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("sessions", help="list the sessions in a store")
    p.add_argument("--db", default="out/station.sqlite")
    p.set_defaults(func=cmd_sessions)

    p = sub.add_parser("export", help="export a stored session as piga-session/1")
    p.add_argument("uid")
    p.add_argument("out_dir")
    p.add_argument("--db", default="out/station.sqlite")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("import", help="import a piga-session/1 directory into a store")
    p.add_argument("session_dir")
    p.add_argument("--db", default="out/station.sqlite")
    p.set_defaults(func=cmd_import)

    for name, func, text in (
        ("gap", cmd_gap, "sim-to-real gap diagnosis of a session"),
        ("gap-validate", cmd_gap_validate, "blind validation of the gap diagnosis"),
    ):
        p = sub.add_parser(name, help=text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(func=func)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (SessionFormatError, TwinConfigError, FitError, StoreError, FileExistsError) as exc:
        print(f"station {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
