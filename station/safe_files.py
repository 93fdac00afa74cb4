"""Files of a session directory from outside, opened as data only: no link is followed, nothing but a regular
file is opened (a FIFO or a device would hang or never end).

`check_tree` refuses a directory that holds a symbolic link or anything but folders and regular files;
`open_regular` opens one file with O_NOFOLLOW and checks, on the open descriptor, that it is the regular file
that was looked at.
"""

from __future__ import annotations

import io
import os
import stat
from pathlib import Path

from station.raw_limits import RawInputError

ALLOWED = "only folders and regular files are read, and no link is followed"


KINDS = (
    (stat.S_ISLNK, "symbolic link"),
    (stat.S_ISFIFO, "FIFO"),
    (stat.S_ISSOCK, "socket"),
    (stat.S_ISCHR, "character device"),
    (stat.S_ISBLK, "block device"),
    (stat.S_ISDIR, "folder"),
)


def _kind(mode: int) -> str:
    return next((name for test, name in KINDS if test(mode)), "special file")


def check_tree(root: Path) -> None:
    """Every entry under `root` (not following links) is a folder or a regular file."""
    stack = [root]
    while stack:
        folder = stack.pop()
        with os.scandir(folder) as entries:
            for e in entries:
                mode = e.stat(follow_symlinks=False).st_mode
                if stat.S_ISDIR(mode):
                    stack.append(Path(e.path))
                elif not stat.S_ISREG(mode):
                    rel = os.path.relpath(e.path, root)
                    raise RawInputError(rel, None, f"a {_kind(mode)}; {ALLOWED}")


def open_regular(path: Path, name: str) -> io.BufferedReader:
    """`path` opened for reading if it is a regular file (checked before and after opening, without following
    a link); RawInputError naming `name` otherwise."""
    try:
        before = os.lstat(path)
    except FileNotFoundError:
        raise RawInputError(name, None, "missing") from None
    if not stat.S_ISREG(before.st_mode):
        raise RawInputError(name, None, f"a {_kind(before.st_mode)}; {ALLOWED}")
    flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise RawInputError(name, None, f"cannot be opened ({exc.strerror}); {ALLOWED}") from None
    after = os.fstat(fd)
    if not stat.S_ISREG(after.st_mode) or (after.st_dev, after.st_ino) != (before.st_dev, before.st_ino):
        os.close(fd)
        raise RawInputError(name, None, f"changed while it was opened; {ALLOWED}")
    return os.fdopen(fd, "rb")
