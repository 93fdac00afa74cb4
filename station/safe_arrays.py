"""Arrays of .npz and HDF5 files from outside, read as data only and within a `Budget` (station.raw_limits).

Before any data is read, every array is checked: a name the caller expects, a real numeric dtype (integers,
floats, booleans: no complex, string, object or compound), the expected number of dimensions, and its size by
its header (.npy) or dataspace (HDF5) against the limits. In HDF5 only hard links and data stored in the file
are read: soft, external and user-defined links, external storage and virtual datasets are refused, and a
chunked dataset's filters must be gzip, shuffle or fletcher32 with every stored chunk inflating to no more than
its declared size (HDF5 itself would inflate a lying chunk without bound). Damaged files are refused with
RawInputError naming the file and the array, never a traceback.
"""

from __future__ import annotations

import math
import os
import struct
import tokenize
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, BinaryIO

import h5py
import numpy as np

from station.raw_limits import Budget, RawInputError
from station.safe_files import open_regular

NUMERIC_KINDS = "biuf"  # booleans, signed and unsigned integers, floats
Spec = tuple[int, str]  # an expected array's number of dimensions and allowed numpy dtype kinds
DTYPES_ALLOWED = "a real numeric dtype (integer, float or bool; no complex, string, object or compound)"
FILTERS = {
    h5py.h5z.FILTER_DEFLATE: "gzip",
    h5py.h5z.FILTER_SHUFFLE: "shuffle",
    h5py.h5z.FILTER_FLETCHER32: "fletcher32",
}
H5_ERRORS = (OSError, RuntimeError, ValueError, KeyError, TypeError, IndexError, OverflowError)
# What numpy and zipfile raise on a damaged archive or .npy header (a header is a Python literal: tokenize and
# ast errors too; an encrypted or unknown-method member: RuntimeError, NotImplementedError).
NPZ_ERRORS = (OSError, ValueError, EOFError, zlib.error, zipfile.BadZipFile, zipfile.LargeZipFile, KeyError,
              TypeError, SyntaxError, tokenize.TokenError, struct.error, RuntimeError, NotImplementedError,
              OverflowError, IndexError, RecursionError)  # fmt: skip


def _check_form(
    dtype: np.dtype, shape: tuple[int, ...], spec: Spec, file: str, dataset: str | None, budget: Budget
) -> None:
    ndim, kinds = spec
    if dtype.kind not in kinds or dtype.fields is not None or dtype.subdtype is not None:
        allowed = DTYPES_ALLOWED if kinds == NUMERIC_KINDS else f"numpy dtype kinds {', '.join(kinds)}"
        raise RawInputError(file, dataset, f"dtype {dtype}; only {allowed} is read")
    if len(shape) != ndim:
        raise RawInputError(file, dataset, f"shape {shape}; expected {ndim} dimension(s)")
    budget.take(math.prod(shape) * dtype.itemsize, file, dataset)


# --- .npz -------------------------------------------------------------------------------------------------


def npy_header(member: IO[bytes], file: str, dataset: str | None) -> tuple[tuple[int, ...], np.dtype]:
    try:
        version = np.lib.format.read_magic(member)
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read(member)
    except NPZ_ERRORS as exc:
        raise RawInputError(file, dataset, f"not a readable .npy array ({exc})") from None
    return shape, dtype


def load_npy(fh: BinaryIO, file: str, budget: Budget, kinds: str = NUMERIC_KINDS) -> np.ndarray:
    """The array of an .npy file (any number of dimensions, a dtype of `kinds`), its header checked against the
    budget and the file's size before the data is read."""
    shape, dtype = npy_header(fh, file, None)
    _check_form(dtype, shape, (len(shape), kinds), file, None, budget)
    held = os.fstat(fh.fileno()).st_size - fh.tell()
    if math.prod(shape) * dtype.itemsize > held:
        raise RawInputError(file, None, f"header claims shape {shape} of {dtype}, more than the {held} bytes it holds")
    fh.seek(0)
    try:
        return np.lib.format.read_array(fh, allow_pickle=False)
    except NPZ_ERRORS as exc:
        raise RawInputError(file, None, f"damaged ({exc})") from None


def load_npz(path: Path, file: str, specs: dict[str, Spec], budget: Budget) -> dict[str, np.ndarray]:
    """The arrays of an .npz named in `specs`, each of its Spec; every header checked (and its size taken
    from `budget`) before any array is read."""
    with open_regular(path, file) as fh:
        try:
            archive = zipfile.ZipFile(fh)
        except NPZ_ERRORS as exc:
            raise RawInputError(file, None, f"not a readable .npz archive ({exc})") from None
        with archive:
            members = {}
            for info in archive.infolist():
                key = info.filename.removesuffix(".npy")
                if not info.filename.endswith(".npy") or key not in specs or key in members:
                    raise RawInputError(file, info.filename, f"not an expected array (allowed, once each: "
                                        f"{', '.join(specs)})")  # fmt: skip
                try:
                    with archive.open(info) as m:
                        shape, dtype = npy_header(m, file, key)
                except NPZ_ERRORS as exc:
                    raise RawInputError(file, key, f"damaged ({exc})") from None
                _check_form(dtype, shape, specs[key], file, key, budget)
                if math.prod(shape) * dtype.itemsize > info.file_size:
                    raise RawInputError(file, key, f"header claims shape {shape} of {dtype}, more than the "
                                        f"{info.file_size} bytes the member holds")  # fmt: skip
                members[key] = info
            out = {}
            for key, info in members.items():
                try:
                    with archive.open(info) as m:
                        out[key] = np.lib.format.read_array(m, allow_pickle=False)
                except NPZ_ERRORS as exc:
                    raise RawInputError(file, key, f"damaged ({exc})") from None
            return out


# --- HDF5 -------------------------------------------------------------------------------------------------


@contextmanager
def open_h5(path: Path, file: str) -> Iterator[h5py.File]:
    """An HDF5 file from outside, opened read-only through a descriptor that follows no link."""
    with open_regular(path, file) as fh:
        try:
            f = h5py.File(fh, "r", locking=False)
        except H5_ERRORS as exc:
            raise RawInputError(file, None, f"not a readable HDF5 file ({exc})") from None
        with f:
            yield f


def member(group: h5py.Group, key: str, file: str) -> h5py.Group | h5py.Dataset:
    """group[key] if it is a hard link (soft, external and user-defined links are refused, never resolved)."""
    where = f"{group.name.rstrip('/')}/{key}"
    link = group.get(key, getlink=True)
    if link is None:
        raise RawInputError(file, where, "missing")
    if isinstance(link, h5py.SoftLink):
        raise RawInputError(file, where, f"a soft link (to {link.path}); only objects stored in the file are read")
    if isinstance(link, h5py.ExternalLink):
        raise RawInputError(file, where, f"an external link (to {link.filename}:{link.path}); only objects stored "
                            "in the file are read")  # fmt: skip
    if not isinstance(link, h5py.HardLink):
        raise RawInputError(file, where, "a user-defined link; only objects stored in the file are read")
    return group[key]


def members(group: h5py.Group, file: str) -> Iterator[tuple[str, h5py.Group | h5py.Dataset]]:
    """(name, object) of each hard link of `group`, refusing any other kind of link."""
    try:
        for key in list(group):
            yield key, member(group, key, file)
    except RawInputError:
        raise
    except H5_ERRORS as exc:
        raise RawInputError(file, group.name, f"damaged HDF5 structure ({exc})") from None


def _check_chunks(ds: h5py.Dataset, file: str, dataset: str, budget: Budget) -> None:
    """Every stored chunk, put through the pipeline's gzip with its output bounded, fits its declared size."""
    dcpl = ds.id.get_create_plist()
    pipeline = [dcpl.get_filter(i)[0] for i in range(dcpl.get_nfilters())]
    unknown = [code for code in pipeline if code not in FILTERS]
    if unknown:
        raise RawInputError(file, dataset, f"HDF5 filter(s) {unknown}; allowed: {', '.join(FILTERS.values())}")
    chunk_bytes = math.prod(ds.chunks) * ds.dtype.itemsize
    if chunk_bytes > budget.limits.max_array_bytes:
        raise RawInputError(file, dataset, f"chunks of {chunk_bytes} bytes; at most {budget.limits.max_array_bytes}")
    if h5py.h5z.FILTER_DEFLATE not in pipeline:
        return
    stored_max = chunk_bytes + chunk_bytes // 256 + 1024  # gzip of incompressible data, a checksum: a little more
    for i in range(ds.id.get_num_chunks()):
        info = ds.id.get_chunk_info(i)
        if info.size > stored_max:
            raise RawInputError(file, dataset, f"a stored chunk of {info.size} bytes; at most {stored_max} for "
                                f"chunks of {chunk_bytes} bytes")  # fmt: skip
        mask, data = ds.id.read_direct_chunk(info.chunk_offset)
        for bit, code in reversed(list(enumerate(pipeline))):
            if mask & (1 << bit):
                continue
            if code == h5py.h5z.FILTER_FLETCHER32:
                data = data[:-4]
            elif code == h5py.h5z.FILTER_DEFLATE:
                inflate = zlib.decompressobj()
                data = inflate.decompress(data, chunk_bytes + 1)
                if len(data) > chunk_bytes:
                    raise RawInputError(file, dataset, f"a chunk inflates to more than its declared {chunk_bytes} "
                                        "bytes")  # fmt: skip


def check_dataset(ds: h5py.Dataset, file: str, spec: Spec, budget: Budget) -> None:
    """A dataset stored in the file, of `spec`'s dimensions and dtype kinds, within the budget."""
    dataset = ds.name
    try:
        if ds.is_virtual:
            raise RawInputError(file, dataset, "a virtual dataset (its data lives in other files); only data stored "
                                "in the file is read")  # fmt: skip
        if ds.external:
            files = ", ".join(str(e[0]) for e in ds.external)
            raise RawInputError(file, dataset, f"external storage (in {files}); only data stored in the file is read")
        if ds.shape is None:
            raise RawInputError(file, dataset, f"an empty dataset (no dataspace); expected a {spec[0]}-D array")
        _check_form(ds.dtype, ds.shape, spec, file, dataset, budget)
        if ds.chunks is not None:
            _check_chunks(ds, file, dataset, budget)
    except RawInputError:
        raise
    except zlib.error as exc:
        raise RawInputError(file, dataset, f"a damaged compressed chunk ({exc})") from None
    except H5_ERRORS as exc:
        raise RawInputError(file, dataset, f"damaged ({exc})") from None


def read_dataset(ds: h5py.Dataset, file: str) -> np.ndarray:
    """A checked dataset's array (check_dataset first)."""
    try:
        return np.asarray(ds[()])
    except H5_ERRORS as exc:
        raise RawInputError(file, ds.name, f"damaged ({exc})") from None


def read_group(group: h5py.Group, file: str, specs: dict[str, Spec], budget: Budget) -> dict[str, np.ndarray]:
    """The datasets of `group` named in `specs`, every one checked before any is read."""
    found = {}
    for key, obj in members(group, file):
        if not isinstance(obj, h5py.Dataset) or key not in specs:
            raise RawInputError(file, obj.name, f"not an expected dataset (allowed: {', '.join(specs)})")
        check_dataset(obj, file, specs[key], budget)
        found[key] = obj
    return {key: read_dataset(ds, file) for key, ds in found.items()}
