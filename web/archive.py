"""piga-session/1 directories as zip archives, for download and upload through the browser."""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from pathlib import Path, PurePosixPath
from typing import BinaryIO

from station.interchange import SessionFormatError, read_session, write_session
from station.session import Session

MAX_UNPACKED_BYTES = 2 << 30  # an upload may hold raw streams, but not fill the disk
MAX_MEMBERS = 10_000


def pack(session: Session, name: str) -> Path:
    """A zip of the session as piga-session/1 (one folder `name` inside), in a fresh temporary directory."""
    work = Path(tempfile.mkdtemp(prefix="panel-export-"))
    write_session(session, work / name)
    return Path(shutil.make_archive(str(work / name), "zip", root_dir=work, base_dir=name))


def unpack(upload: BinaryIO, into: Path) -> Session:
    """Read and validate an uploaded zip of a piga-session/1 directory (session.json at its root or in one folder).

    SessionFormatError names the defect, as for `station import`; members that would land outside `into`,
    too many members or too many bytes are refused before anything is written.
    """
    try:
        archive = zipfile.ZipFile(upload)
    except zipfile.BadZipFile:
        raise SessionFormatError("upload", "not a zip archive of a piga-session/1 directory") from None
    with archive:
        members = archive.infolist()
        if len(members) > MAX_MEMBERS:
            raise SessionFormatError("upload", f"{len(members)} files in the archive; at most {MAX_MEMBERS}")
        if sum(m.file_size for m in members) > MAX_UNPACKED_BYTES:
            raise SessionFormatError("upload", f"unpacks to more than {MAX_UNPACKED_BYTES >> 20} MiB")
        for m in members:
            path = PurePosixPath(m.filename)
            if path.is_absolute() or ".." in path.parts:
                raise SessionFormatError("upload", "member path outside the archive", value=m.filename)
        archive.extractall(into)
    found = sorted(into.glob("session.json")) or sorted(into.glob("*/session.json"))
    if len(found) != 1:
        raise SessionFormatError("upload", "expected one session.json, at the root or in one folder")
    return read_session(found[0].parent)
