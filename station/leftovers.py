"""Temporary files of a write that a killed process left behind, found and removed at the next open of the store.

A writer holds an exclusive flock on its temporary file (`writing`) for as long as it writes; the lock dies with
its process. So a temporary file that nobody holds locked is a leftover of a killed import or run
(`remove_leftovers`), while one that a live process (another station, the panel) is writing is left alone.
"""

from __future__ import annotations

import fcntl
import os
import stat
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

SUFFIX = ".tmp"  # every temporary file of the store ends so (a point's `.000001.h5.tmp`, an import's marker)
_OPEN = os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)


def _same_file(fd: int, path: Path) -> bool:
    try:
        st = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    fst = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (fst.st_dev, fst.st_ino)


@contextmanager
def writing(tmp: Path) -> Iterator[Path]:
    """`tmp` created (empty) and held locked while the caller writes it and renames it into place."""
    for _ in range(3):  # a cleaner may take the file between its creation and our lock: make it again
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | _OPEN, 0o644)
        fcntl.flock(fd, fcntl.LOCK_EX)
        if _same_file(fd, tmp):
            break
        os.close(fd)
    else:
        raise OSError(f"{tmp}: removed as a leftover three times while it was being created")
    try:
        yield tmp
    finally:
        os.close(fd)


def remove_leftovers(root: Path, before_unlink: Callable[[Path], None] = lambda p: None) -> list[Path]:
    """Every `*.tmp` regular file under `root` that no live process holds locked, removed (after
    `before_unlink(path)`, called while it is locked); the removed paths."""
    removed: list[Path] = []
    if not root.is_dir():
        return removed
    for path in sorted(root.rglob(f"*{SUFFIX}")):
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | _OPEN)
        except OSError:  # a link, or gone meanwhile: not ours to remove
            continue
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise BlockingIOError  # not a file the store wrote
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:  # a live writer
            os.close(fd)
            continue
        try:
            if _same_file(fd, path):
                before_unlink(path)
                path.unlink()
                removed.append(path)
        finally:
            os.close(fd)
    return removed
