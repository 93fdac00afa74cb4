"""Raw streams in HDF5: chunked, compressed, one group per point, flushed after each point.

A raw record of one window (5 kHz grating, every pulse edge) is tens of megabytes; a session holds gigabytes.
So raw streams are written point by point (`RawWriter.add`: the group, then a flush, so a crash keeps every
finished point readable) and read point by point (`LazyRaw`: a mapping that loads a point's arrays when asked),
never all at once. Used by the interchange (raw.h5 of a piga-session/1 directory) and the store (one file per
point beside the SQLite file). Every read goes through station.safe_arrays: no link followed, only the expected
1-D numeric datasets, sizes checked against station.raw_limits before the data is read.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import h5py
import numpy as np

from station import leftovers
from station.leftovers import writing
from station.raw_limits import DEFAULT_LIMITS, Budget, RawInputError, RawLimits
from station.safe_arrays import NUMERIC_KINDS, Spec, member, open_h5, read_group
from station.session import RAW_FIELDS, RawStreams

REQUIRED = ("grating_t", "grating_z", "pulse_t")
RAW_SPECS: dict[str, Spec] = {name: (1, NUMERIC_KINDS) for name in RAW_FIELDS}  # every raw stream: 1-D numeric
CHUNK = 1 << 16  # elements per chunk: 512 KiB of float64
COMPRESSION = {"compression": "gzip", "compression_opts": 1, "shuffle": True}  # shuffle: times compress ~3x


def _group_name(point_id: str) -> str:
    """A point id as an HDF5 group name ('/' would make a path; '.' is the file itself)."""
    if not point_id or "/" in point_id or point_id in (".", ".."):
        raise ValueError(f"point_id {point_id!r}: not allowed as a raw record name (no '/', not empty)")
    return point_id


def write_arrays(group: h5py.Group, raw: RawStreams) -> None:
    """The point's arrays as chunked, compressed datasets of `group`."""
    for name in RAW_FIELDS:
        a = getattr(raw, name)
        if a is None:
            continue
        a = np.ascontiguousarray(a)
        chunks = (min(CHUNK, a.size),) if a.size else None
        group.create_dataset(name, data=a, chunks=chunks, **(COMPRESSION if a.size else {}))


def read_arrays(group: h5py.Group, file: str, budget: Budget) -> RawStreams:
    """A point's raw streams from its group, checked (station.safe_arrays) and taken from `budget`."""
    try:
        return RawStreams.from_arrays(read_group(group, file, RAW_SPECS, budget))
    except RawInputError:
        raise
    except ValueError as exc:  # a required stream missing
        raise RawInputError(file, group.name, str(exc)) from None


class RawWriter:
    """raw streams of many points into one HDF5 file, each point flushed to disk before the next."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._file = h5py.File(self.path, "w", locking=False)

    def add(self, point_id: str, raw: RawStreams) -> None:
        write_arrays(self._file.create_group(_group_name(point_id)), raw)
        self._file.flush()

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> RawWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_point_file(path: str | os.PathLike, raw: RawStreams) -> None:
    """One point's raw streams as a file of their own: written under a temporary name, flushed to disk, renamed,
    so that the file either holds the whole point or does not exist."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with writing(path.with_name(f".{path.name}{leftovers.SUFFIX}")) as tmp:  # locked: not a leftover while written
        with h5py.File(tmp, "w", locking=False) as f:
            write_arrays(f, raw)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)


def read_point_file(path: str | os.PathLike, limits: RawLimits = DEFAULT_LIMITS) -> RawStreams:
    path = Path(path)
    with open_h5(path, path.name) as f:
        return read_arrays(f, path.name, Budget(limits))


class LazyRaw(Mapping[str, RawStreams]):
    """point_id -> RawStreams, each read from its HDF5 location only when asked (and not kept)."""

    def __init__(
        self,
        locations: Mapping[str, tuple[Path, str]],
        loaded: Mapping[str, RawStreams] | None = None,
        limits: RawLimits = DEFAULT_LIMITS,
    ) -> None:
        self._where = dict(locations)  # point_id -> (file, group inside it; "/" for a file of its own)
        self._limits = limits  # each point's read: every array within limits.max_array_bytes
        self._loaded = dict(loaded or {})  # points already in memory (raw streams of an older store's blobs)
        self.digests: dict[str, bytes] = {}  # point_id -> SHA-256 of its arrays, where a reader computed it

    @classmethod
    def of_file(cls, path: Path, point_ids: Iterable[str], limits: RawLimits = DEFAULT_LIMITS) -> LazyRaw:
        return cls({pid: (path, _group_name(pid)) for pid in point_ids}, limits=limits)

    def __getitem__(self, point_id: str) -> RawStreams:
        if point_id in self._loaded:
            return self._loaded[point_id]
        path, group = self._where[point_id]
        with open_h5(path, path.name) as f:
            where = f if group == "/" else member(f, group, path.name)
            if not isinstance(where, h5py.Group):
                raise RawInputError(path.name, group, "expected a group of raw streams")
            return read_arrays(where, path.name, Budget(self._limits))

    def __contains__(self, point_id: object) -> bool:  # without reading the arrays
        return point_id in self._loaded or point_id in self._where

    def __iter__(self) -> Iterator[str]:
        return iter([*self._loaded, *self._where])

    def __len__(self) -> int:
        return len(self._loaded) + len(self._where)

    def __repr__(self) -> str:
        return f"LazyRaw({len(self)} points)"
