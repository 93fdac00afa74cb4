"""`station sync STORE --to postgresql://...` and the sync after each run of `station serve --sync-to`.

SQLAlchemy and the sync are imported when a sync runs, not when the `station` command starts.
"""

from __future__ import annotations

import argparse
import logging
import socket
import sys
from pathlib import Path

from station.errors import StationError
from station.store import SessionStore, StoreError

log = logging.getLogger(__name__)
URL_HELP = (
    "central PostgreSQL database, e.g. postgresql://station@db.lab/calibration (a password goes in "
    "~/.pgpass or PGPASSWORD, never on the command line)"
)
ARRAYS_HELP = "the lab's array root, a directory every station and the panel reach (raw arrays as .npy files)"


def add_sync_command(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sync", help="push a store's ended sessions to the central history (PostgreSQL)")
    p.add_argument("store", help="the station's SQLite session store (e.g. out/station.sqlite)")
    p.add_argument("--to", required=True, metavar="URL", help=URL_HELP)
    p.add_argument("--arrays", required=True, metavar="DIR", help=ARRAYS_HELP)
    p.add_argument(
        "--name",
        default=socket.gethostname(),
        help="the station's name in the history when a session's provenance has none (default: host)",
    )
    p.add_argument("--uid", nargs="+", metavar="UID", help="only these sessions (default: every ended session)")
    p.set_defaults(func=cmd_sync)


def add_serve_options(p: argparse.ArgumentParser) -> None:
    """`station serve --sync-to URL --sync-arrays DIR`: push each session to the central history once it ends."""
    p.add_argument("--sync-to", metavar="URL", help="after each session, sync the store here; " + URL_HELP)
    p.add_argument("--sync-arrays", metavar="DIR", help="with --sync-to: " + ARRAYS_HELP)


def cmd_sync(args: argparse.Namespace) -> int:
    """0 when every ended session is in the central history, 1 if any was refused (conflict), 2 on an error."""
    if not Path(args.store).is_file():
        print(f"station sync: error: {args.store}: no session store there", file=sys.stderr)
        return 2
    import sqlalchemy as sa

    from station.central.sync import open_central, sync_store

    try:
        engine = open_central(args.to)
        with SessionStore(args.store) as store:
            report = sync_store(
                store,
                engine,
                args.arrays,
                args.name,
                uids=args.uid,
                progress=lambda uid, outcome: print(f"{uid}: {outcome}", flush=True),
            )
        engine.dispose()
    except (StationError, sa.exc.OperationalError, OSError) as exc:
        print(f"station sync: error: {_first_line(exc)}", file=sys.stderr)
        return 2
    print(report.summary())
    for message in report.conflicts:
        print(f"station sync: refused: {message}", file=sys.stderr)
    return 1 if report.conflicts else 0


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


class SyncAfterRun:
    """Called by the controller once a run has ended (and its analysis is stored): pushes that session and any
    ended session of the store the central history lacks. A failure (database unreachable) is logged and
    left for the next run or a `station sync`: the station's own store stays the journal."""

    def __init__(self, store: SessionStore, url: str, arrays: str | Path, station: str) -> None:
        from station.central.sync import SyncReport, open_central

        if not arrays:
            raise StoreError("--sync-to needs --sync-arrays DIR: where the raw arrays go")
        self.store, self.arrays, self.station = store, Path(arrays), station
        self.engine = open_central(url)
        self.last: SyncReport | None = None

    def pending(self, uid: str) -> list[str]:
        """The session just run and the store's sessions the central history does not hold yet."""
        import sqlalchemy as sa

        uids = [r["uid"] for r in self.store.sessions()]
        with self.engine.connect() as conn:
            if conn.execute(sa.text("SELECT to_regclass('sessions')")).scalar() is None:
                return uids
            known = set(conn.execute(sa.text("SELECT uid FROM sessions WHERE uid = ANY(:u)"), {"u": uids}).scalars())
        return [u for u in uids if u == uid or u not in known]

    def __call__(self, outcome: object) -> None:
        uid = getattr(outcome, "session_uid", "")
        from station.central.sync import sync_store

        try:
            self.last = sync_store(self.store, self.engine, self.arrays, self.station, uids=self.pending(uid))
        except Exception as exc:  # the station carries on; the next sync pushes what this one could not
            log.error("sync of session %s to the central history failed: %s", uid, _first_line(exc))
            print(f"station serve: sync of {uid} failed: {_first_line(exc)}", file=sys.stderr, flush=True)
            return
        print(f"station serve: sync after {uid}: {self.last.summary()}", flush=True)
        for message in self.last.conflicts:
            print(f"station serve: sync refused: {message}", file=sys.stderr, flush=True)

    def close(self) -> None:
        self.engine.dispose()
