"""Central history: history queries over 100 000 sessions (goal: under 100 ms, issue 16) and sync time per session.

(a) A throwaway PostgreSQL (station.central.server; or --url an existing empty database) migrated to the
    central schema, bulk-loaded (COPY) with N synthetic session rows: 30 stations, 2000 instrument serials,
    8 procedures, statuses 80% finished / 12% aborted / 5% imported / 3% failed, created over three years.
    Each history query of the panel (CentralStore.history, limit 200, newest first) timed REPEATS times
    after one warm-up: median and worst, in ms, with the rows it returned.
(b) `station sync` of seed-000 sessions of 40 points from the twin (without raw streams, as most stores hold
    them; one with the raw streams of 2 real windows): wall time per session, first sync and re-sync.

    .venv/bin/python bench/bench_central.py [N] [--url postgresql://...]

Simulation path: (b)'s sessions are the session_sim shortcut (not the engine): station.twin.session_sim, data to sync.
"""

from __future__ import annotations

import argparse
import io
import os
import random
import statistics
import tempfile
import time
from datetime import UTC, date, datetime, timedelta
from pathlib import Path

import sqlalchemy as sa

from station.central.migrations import migrate
from station.central.reader import CentralStore, HistoryQuery
from station.central.server import ThrowawayServer
from station.central.sync import open_central, sync_store
from station.store import SessionStore
from station.twin.config import default_twin
from station.twin.plan import seed000_plan
from station.twin.session_sim import simulate_session

REPEATS = 20
PROCEDURES = ("integral_precession", "integral_precession.integer_periodic_vibration",
              "integral_precession.multi_frequency", "integral_precession.self_alignment", "tumble",
              "rlg_g_sensitivity", "multiposition", "nonlinear_suppression")  # fmt: skip
STATUSES = ("finished",) * 80 + ("aborted",) * 12 + ("imported",) * 5 + ("failed",) * 3
T0 = datetime(2024, 1, 1, tzinfo=UTC)


def bulk_load(engine: sa.Engine, n: int) -> None:
    rng = random.Random(16)
    buf = io.StringIO()
    for k in range(n):
        created = T0 + timedelta(seconds=rng.uniform(0, 3 * 365 * 86400))
        h = f"{rng.getrandbits(256):064x}"
        fields = [f"S{k:07d}-{h[:8]}", f"station-{rng.randrange(30):02d}", created.isoformat(),
                  rng.choice(PROCEDURES), f"PIGA-{rng.randrange(2000):04d}", rng.choice(STATUSES), "{}", "{}", "",
                  "40", "3", h, h, h]  # fmt: skip
        buf.write("\t".join(fields) + "\n")
    buf.seek(0)
    raw = engine.raw_connection()
    try:
        with raw.cursor() as cur:
            cols = ("uid, station, created_utc, procedure, instrument_serial, status, station_json, config_json, notes,"
                    " n_points, n_measurements, head_sha256, catalog_sha256, content_sha256")  # fmt: skip
            with cur.copy(f"COPY sessions ({cols}) FROM STDIN") as copy:
                copy.write(buf.read())
            cur.execute("ANALYZE sessions")
        raw.commit()
    finally:
        raw.close()


QUERIES = {
    "newest 200, no filter": HistoryQuery(),
    "one station": HistoryQuery(station="station-07"),
    "part of a serial (any case)": HistoryQuery(serial="iga-042"),
    "one serial, whole": HistoryQuery(serial="PIGA-1234"),
    "procedure + status": HistoryQuery(procedure="rlg_g_sensitivity", status="failed"),
    "one month": HistoryQuery(since=date(2025, 6, 1), until=date(2025, 6, 30)),
    "station + serial part + a year": HistoryQuery(
        serial="-01", station="station-11", since=date(2025, 1, 1), until=date(2025, 12, 31)
    ),
    "a serial no session has": HistoryQuery(serial="ZZZ-9"),
}


def time_queries(url: str) -> None:
    with CentralStore(url, Path(tempfile.gettempdir())) as central:
        print("| query | rows | median ms | worst ms |")
        print("|---|---|---|---|")
        for name, q in QUERIES.items():
            rows = central.history(q, 200)
            walls = []
            for _ in range(REPEATS):
                t = time.perf_counter()
                central.history(q, 200)
                walls.append(1e3 * (time.perf_counter() - t))
            print(f"| {name} | {len(rows)} | {statistics.median(walls):.1f} | {max(walls):.1f} |")


def time_sync(url: str, n_sessions: int) -> None:
    twin = default_twin()
    with tempfile.TemporaryDirectory() as tmp, SessionStore(Path(tmp) / "s.sqlite") as store:
        for k in range(n_sessions):
            s = simulate_session(seed000_plan(), twin, seed=k, raw=k == 0)
            uid = store.create_session(s.station, "integral_precession", instrument_serial=f"PIGA-{k:04d}")
            for i, p in enumerate(s.points):
                store.add_point(uid, p, s.raw.get(p.point_id) if i < 2 else None)
            store.add_event(uid, "end", "finished")
            store.add_result(uid, "integral", {"kz": 1e-3})
            store.set_status(uid, "finished")
        engine = open_central(url)
        arrays = Path(tmp) / "arrays"
        raw_uid = store.sessions()[0]["uid"]
        t = time.perf_counter()
        first = sync_store(store, engine, arrays, "bench", uids=[raw_uid])
        raw_s = time.perf_counter() - t
        first_rest = sync_store(store, engine, arrays, "bench")
        again = sync_store(store, engine, arrays, "bench")
        engine.dispose()
    n = n_sessions - 1
    print("\n| sync of 40-point sessions | sessions | wall s | per session ms |\n|---|---|---|---|")
    print(f"| first sync, no raw streams | {n} | {first_rest.wall_s:.2f} | {1e3 * first_rest.wall_s / n:.0f} |")
    print(f"| re-sync (nothing to add) | {n_sessions} | {again.wall_s:.2f} | {1e3 * again.wall_s / n_sessions:.0f} |")
    print(f"| first sync, raw streams of 2 windows ({first.bytes_written / 1e6:.0f} MB in {first.files_written} files)"
          f" | 1 | {raw_s:.2f} | {1e3 * raw_s:.0f} |")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("n", nargs="?", type=int, default=100_000, help="synthetic sessions (default 100000)")
    p.add_argument("--url", help="an existing, empty PostgreSQL database (default: a throwaway server)")
    p.add_argument("--sync-sessions", type=int, default=21)
    args = p.parse_args()
    server = None if args.url else ThrowawayServer(database="bench").start()
    try:
        url = args.url or server.url
        engine = open_central(url)
        migrate(engine)
        t = time.perf_counter()
        bulk_load(engine, args.n)
        print(f"{args.n} synthetic sessions bulk-loaded in {time.perf_counter() - t:.1f} s; "
              f"load average {os.getloadavg()[0]:.1f}\n")  # fmt: skip
        engine.dispose()
        time_queries(url)
        time_sync(url, args.sync_sessions)
        print(f"\nload average after: {os.getloadavg()[0]:.1f}")
    finally:
        if server is not None:
            server.stop()


if __name__ == "__main__":
    main()
