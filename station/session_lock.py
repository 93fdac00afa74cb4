"""One process per session: an advisory lock per session, held while a run of it lives.

A run (new or resumed) holds `flock(LOCK_EX)` on `<store>.locks/<uid>.lock`, which
the kernel releases when the process ends in any way (kill -9 included). So a
session whose status is `running` but whose lock is free has no live process:
`recover_interrupted(store)` marks such sessions `interrupted` (resumable,
reportable, diagnosable like an aborted one). A second process that tries to run
or resume a locked session gets SessionLocked naming who holds it. Creating a
session and taking its lock happen under a store-wide `_create.lock`, which the
recovery scan takes too, so a session being born is never taken for a dead one.
Lock files are never deleted (deleting a flock'ed file races with its next user).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

from station.store import SessionStore, StoreError

INTERRUPTED = "interrupted"


class SessionLocked(StoreError):  # noqa: N818 - a state, named as the operator reads it
    """Another process (or run) holds the session."""


def lock_dir(store_path: str | Path) -> Path:
    path = Path(store_path)
    return path.with_name(path.name + ".locks")


def _open(path: Path) -> int:
    path.parent.mkdir(parents=True, exist_ok=True)
    return os.open(path, os.O_RDWR | os.O_CREAT, 0o600)


class SessionLock:
    """The held lock of one session; release() (or process exit) frees it."""

    def __init__(self, store_path: str | Path, uid: str) -> None:
        self.uid = uid
        self.path = lock_dir(store_path) / f"{uid}.lock"
        fd = _open(self.path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = self.path.read_text(errors="replace").strip() or "{}"
            os.close(fd)
            raise SessionLocked(
                f"session {uid} is being run by another process ({holder}): one process per session; "
                "wait for it to end, or abort it from its console or the panel"
            ) from None
        who = {"pid": os.getpid(), "host": socket.gethostname(), "since_utc": datetime.now(UTC).isoformat()}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(who).encode(), 0)
        self._fd: int | None = fd

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, 0)
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None

    def __enter__(self) -> SessionLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


@contextlib.contextmanager
def creating(store_path: str | Path) -> Iterator[None]:
    """The store-wide lock under which a session is created and locked, and the recovery scan runs."""
    fd = _open(lock_dir(store_path) / "_create.lock")
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def is_locked(store_path: str | Path, uid: str) -> bool:
    """Some live process holds the session's lock (this one included)."""
    try:
        SessionLock(store_path, uid).release()
    except SessionLocked:
        return True
    return False


def recover_interrupted(store: SessionStore) -> list[str]:
    """Mark every `running` session without a live process `interrupted`; their uids."""
    found = []
    with creating(store.path):
        for row in store.sessions():
            if row["status"] != "running" or is_locked(store.path, row["uid"]):
                continue
            store.set_status(row["uid"], INTERRUPTED)
            store.add_event(row["uid"], "interrupted", "found running with no live process: marked interrupted "
                            "(resumable; its finished points are kept)", "warning")  # fmt: skip
            found.append(row["uid"])
    return found
