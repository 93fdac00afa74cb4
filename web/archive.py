"""piga-session/1 directories as zip archives, for download and upload through the browser.

An upload is bounded before anything is decompressed, nested archives included:
the upload itself (MAX_UPLOAD_BYTES, also enforced on the request body by
web.app), the number of members, and the decompressed bytes of every member and
of every member of a member that is itself a zip (an .npz of raw streams, or a
zip in a zip), counted together against MAX_UNPACKED_BYTES. An array inside an
.npz is bounded by its header (shape x itemsize) before numpy loads it, and
object arrays are refused. Archives nested deeper than one level are refused.
Members are copied out in chunks and never beyond their declared size (zipfile
stops there and checks the CRC), so a lying header cannot overrun the bound.
The session's arrays are then read within `UPLOAD_LIMITS` (station.raw_limits):
what raw.h5's compressed datasets and the .npz arrays hold once decompressed is
bounded by MAX_UNPACKED_BYTES too, each array by UPLOAD_ARRAY_BYTES, whatever the
compression, and checked before it is read.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path, PurePosixPath
from typing import IO, BinaryIO

from station.interchange import SessionFormatError, read_session, write_session
from station.raw_limits import RawInputError, RawLimits
from station.safe_arrays import npy_header
from station.session import Session

MAX_UPLOAD_BYTES = 256 << 20  # the zip as uploaded
MAX_UNPACKED_BYTES = 1 << 30  # every member and nested member, decompressed, together
MAX_MEMBERS = 10_000  # members, nested ones included
ZIP_MAGIC = b"PK\x03\x04"
CHUNK_BYTES = 1 << 20
UPLOAD_ARRAY_BYTES = 128 << 20  # one decompressed array of an uploaded session (a long window's stream: ~100 MB)
UPLOAD_LIMITS = RawLimits(max_array_bytes=UPLOAD_ARRAY_BYTES, max_session_bytes=MAX_UNPACKED_BYTES)


def pack(session: Session, name: str) -> Path:
    """A zip of the session as piga-session/1 (one folder `name` inside), in a fresh temporary directory."""
    work = Path(tempfile.mkdtemp(prefix="panel-export-"))
    write_session(session, work / name)
    return Path(shutil.make_archive(str(work / name), "zip", root_dir=work, base_dir=name))


class _Budget:
    """Decompressed bytes and members left for one upload."""

    def __init__(self) -> None:
        self.bytes_left = MAX_UNPACKED_BYTES
        self.members_left = MAX_MEMBERS

    def take(self, nbytes: int, where: str) -> None:
        self.members_left -= 1
        self.bytes_left -= nbytes
        if self.members_left < 0:
            raise SessionFormatError("upload", f"more than {MAX_MEMBERS} files in the archive (nested ones counted)")
        if self.bytes_left < 0:
            raise SessionFormatError(
                "upload", f"unpacks to more than {MAX_UNPACKED_BYTES >> 20} MiB (at {where}, nested archives counted)"
            )


# What unpacking a damaged or unusual member raises: a bad header or CRC, a broken deflate stream, a member cut
# short, a compression method or encryption zipfile does not read, a name the file system refuses.
DAMAGED = (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError, ValueError, OSError)


@contextmanager
def _member(where: str) -> Iterator[None]:
    """A damaged member as a SessionFormatError naming it (never an exception from inside zipfile)."""
    try:
        yield
    except SessionFormatError:
        raise
    except DAMAGED as exc:
        raise SessionFormatError(
            "upload", f"a member that cannot be unpacked ({type(exc).__name__}: {exc})", column=where
        ) from None


def _npy_bytes(member: IO[bytes], where: str) -> int:
    """Bytes an .npy member decompresses to by its header (shape x itemsize); object arrays refused."""
    try:
        shape, dtype = npy_header(member, "upload", where)
    except RawInputError as exc:
        raise SessionFormatError("upload", exc.reason, column=where) from None
    if dtype.hasobject:
        raise SessionFormatError("upload", "object arrays are not allowed", column=where, value=str(dtype))
    return math.prod(shape) * dtype.itemsize


def _check_nested(path: Path, where: str, budget: _Budget) -> None:
    """A member that is a zip: each of its members bounded by its declared size and, for arrays, by its header."""
    try:
        nested = zipfile.ZipFile(path)
    except DAMAGED:
        raise SessionFormatError("upload", "a damaged archive inside the archive", column=where) from None
    with nested:
        for info in nested.infolist():
            inner = f"{where}/{info.filename}"
            budget.take(info.file_size, inner)
            with _member(inner), nested.open(info) as member:
                head = member.read(len(ZIP_MAGIC))
                if head == ZIP_MAGIC:
                    raise SessionFormatError("upload", "archives nested more than one level deep", column=inner)
            if info.filename.endswith(".npy"):
                with _member(inner), nested.open(info) as member:
                    declared = _npy_bytes(member, inner)
                if declared > info.file_size:
                    raise SessionFormatError("upload", f"array header claims {declared} bytes, the member holds "
                                             f"{info.file_size}", column=inner)  # fmt: skip


def _copy_out(archive: zipfile.ZipFile, info: zipfile.ZipInfo, dst: Path) -> None:
    """One member to dst in chunks, never beyond its declared size."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    written = 0
    with _member(info.filename), archive.open(info) as src, dst.open("wb") as out:
        while chunk := src.read(CHUNK_BYTES):
            written += len(chunk)
            if written > info.file_size:
                raise SessionFormatError("upload", "a member unpacks beyond its declared size", column=info.filename)
            out.write(chunk)


def _upload_size(upload: BinaryIO) -> int:
    pos = upload.tell()
    size = upload.seek(0, 2)
    upload.seek(pos)
    return size


def unpack(upload: BinaryIO, into: Path) -> Session:
    """Read and validate an uploaded zip of a piga-session/1 directory (session.json at its root or in one folder).

    SessionFormatError names the defect, as for `station import`; an upload over any bound of the module
    docstring, or with members that would land outside `into`, is refused before it is decompressed.
    """
    size = _upload_size(upload)
    if size > MAX_UPLOAD_BYTES:
        raise SessionFormatError("upload", f"{size >> 20} MiB uploaded; at most {MAX_UPLOAD_BYTES >> 20} MiB")
    try:
        archive = zipfile.ZipFile(upload)
    except DAMAGED:
        raise SessionFormatError("upload", "not a zip archive of a piga-session/1 directory") from None
    budget = _Budget()
    with archive:
        members = [m for m in archive.infolist() if not m.is_dir()]
        for m in members:
            path = PurePosixPath(m.filename)
            if path.is_absolute() or ".." in path.parts:
                raise SessionFormatError("upload", "member path outside the archive", value=m.filename)
            budget.take(m.file_size, m.filename)
        for m in members:
            dst = into / m.filename
            _copy_out(archive, m, dst)
            with dst.open("rb") as f:
                is_zip = f.read(len(ZIP_MAGIC)) == ZIP_MAGIC
            if is_zip:
                _check_nested(dst, m.filename, budget)
    found = sorted(into.glob("session.json")) or sorted(into.glob("*/session.json"))
    if len(found) != 1:
        raise SessionFormatError("upload", "expected one session.json, at the root or in one folder")
    return read_session(found[0].parent, UPLOAD_LIMITS)
