"""Issue 30 (1, 2, 4): a session directory from outside is read as data only, within stated limits, and a killed
writer's temporary files go at the next open of the store.

Every hostile file is built here with h5py, numpy and zipfile. Each case is refused with a SessionFormatError that
names the file and the dataset and says what is allowed; an import of it stores nothing; and the refusal comes
before any array is read (`no_reads` fails the test if one is), so memory cannot grow with what a file declares.
"""

import fcntl
import io
import logging
import os
import shutil
import tracemalloc
import zipfile
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from session_files import refused

import station.safe_arrays
from station.cli.cli import main
from station.interchange import SessionFormatError, read_session, write_session
from station.raw_limits import DEFAULT_LIMITS, MiB, RawInputError, RawLimits
from station.rawfile import read_point_file
from station.safe_files import open_regular
from station.store import SessionStore
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session

# Limits this file relies on: the defaults (512 MiB per array, 8 GiB per session) and, where a test says so,
# tight ones; memory: the gzip bomb's check may hold at most TRACED_PEAK bytes (one declared chunk, 800 kB here).
TRACED_PEAK = 4 * MiB
BOMB_BYTES = 64 * MiB  # what the lying chunk inflates to; HDF5 itself would allocate all of it


@pytest.fixture(scope="module")
def session():
    return simulate_session(multiposition_plan([0.0], [10.0], window_s=2.0), TwinConfig(), seed=3, raw=True)


@pytest.fixture
def good(tmp_path, session) -> Path:
    return write_session(session, tmp_path / "s")


@pytest.fixture
def pid(session) -> str:
    return next(iter(session.raw))


@pytest.fixture
def no_reads(monkeypatch):
    """Fails the test if any HDF5 dataset or .npy array is read: the refusal must come first."""

    def forbidden(*args, **kwargs):
        raise AssertionError("an array was read before the file was refused")

    monkeypatch.setattr(station.safe_arrays, "read_dataset", forbidden)
    monkeypatch.setattr(station.safe_arrays.np.lib.format, "read_array", forbidden)


def _swap(good: Path, pid: str, name: str, make) -> None:
    """raw.h5's dataset /pid/name replaced by what make(group, name) puts there."""
    with h5py.File(good / "raw.h5", "r+") as f:
        del f[pid][name]
        make(f[pid], name)


# --- links and storage outside the file --------------------------------------------------------------------


def test_an_external_link_to_a_file_outside_is_refused(good, pid, tmp_path, no_reads):
    outside = tmp_path / "outside.h5"
    with h5py.File(outside, "w") as f:
        f["secret"] = np.arange(10.0)
    _swap(good, pid, "grating_t", lambda g, n: g.__setitem__(n, h5py.ExternalLink(str(outside), "/secret")))
    msg = refused(good, tmp_path, "raw.h5", f"/{pid}/grating_t", "an external link", "only objects stored in the file")
    assert str(outside) in msg


def test_external_storage_pointing_at_etc_passwd_is_refused(good, pid, tmp_path, no_reads):
    size = os.path.getsize("/etc/passwd") // 8
    _swap(
        good, pid, "pulse_t", lambda g, n: g.create_dataset(n, (size,), "<f8", external=[("/etc/passwd", 0, size * 8)])
    )
    refused(good, tmp_path, f"/{pid}/pulse_t", "external storage (in /etc/passwd)", "only data stored in the file")


@pytest.mark.parametrize("target", ["grating_t", "/nowhere"], ids=["soft", "dangling"])
def test_soft_links_are_refused_dangling_or_not(good, pid, tmp_path, target, no_reads):
    path = f"/{pid}/{target}" if not target.startswith("/") else target
    _swap(good, pid, "grating_z", lambda g, n: g.__setitem__(n, h5py.SoftLink(path)))
    refused(good, tmp_path, f"/{pid}/grating_z", f"a soft link (to {path})")


def test_a_virtual_dataset_is_refused(good, pid, tmp_path, no_reads):
    outside = tmp_path / "outside.h5"
    with h5py.File(outside, "w") as f:
        f["x"] = np.arange(100.0)
    layout = h5py.VirtualLayout((100,), "<f8")
    layout[:] = h5py.VirtualSource(str(outside), "x", (100,))
    _swap(good, pid, "pulse_t", lambda g, n: g.create_virtual_dataset(n, layout))
    refused(good, tmp_path, f"/{pid}/pulse_t", "a virtual dataset")


def test_a_symlinked_npz_to_dev_zero_is_refused(good, pid, tmp_path):
    (good / "raw.h5").unlink()
    (good / "raw").mkdir()
    (good / "raw" / f"{pid}.npz").symlink_to("/dev/zero")
    refused(good, tmp_path, f"raw/{pid}.npz", "a symbolic link", "no link is followed")
    with pytest.raises(RawInputError, match="a character device; only folders and regular files"):
        open_regular(Path("/dev/zero"), "zero")  # and opened directly, it is not opened at all


def test_a_symlinked_raw_h5_and_a_symlink_anywhere_are_refused(good, tmp_path):
    shutil.move(good / "raw.h5", tmp_path / "elsewhere.h5")
    (good / "raw.h5").symlink_to(tmp_path / "elsewhere.h5")
    refused(good, tmp_path, "raw.h5: a symbolic link")
    (good / "raw.h5").unlink()
    (good / "deep" / "er").mkdir(parents=True)
    (good / "deep" / "er" / "passwd").symlink_to("/etc/passwd")
    refused(good, tmp_path, "deep/er/passwd: a symbolic link")


def test_a_fifo_in_the_session_directory_is_refused_without_opening_it(good, tmp_path):
    os.mkfifo(good / "notes.txt")
    refused(good, tmp_path, "notes.txt: a FIFO")
    os.unlink(good / "notes.txt")
    os.unlink(good / "raw.h5")
    os.mkfifo(good / "raw.h5")  # opened, a FIFO with no writer would block the reader for ever
    refused(good, tmp_path, "raw.h5: a FIFO")


# --- sizes declared by the file ------------------------------------------------------------------------------


def _npz(path: Path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(f"{name}.npy", data)


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


def _as_npz(good: Path, session, pid: str) -> dict[str, bytes]:
    (good / "raw.h5").unlink()
    (good / "raw").mkdir()
    raw = session.raw[pid]
    return {n: _npy(getattr(raw, n)) for n in ("grating_t", "grating_z", "pulse_t")}


def test_an_npy_header_claiming_1e12_elements_is_refused_before_reading(good, session, pid, tmp_path, no_reads):
    members = _as_npz(good, session, pid)
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)})
    members["pulse_t"] = header.getvalue() + b"\0" * 64
    _npz(good / "raw" / f"{pid}.npz", members)
    refused(good, tmp_path, f"raw/{pid}.npz", "dataset 'pulse_t'", "declares 8000000000000 bytes",
             f"at most {DEFAULT_LIMITS.max_array_bytes} bytes (512 MiB) per array")  # fmt: skip


def test_an_npy_header_larger_than_its_member_is_refused(good, session, pid, tmp_path, no_reads):
    members = _as_npz(good, session, pid)
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**6,)})
    members["pulse_t"] = header.getvalue() + b"\0" * 64  # 8 MB claimed, 64 bytes held
    _npz(good / "raw" / f"{pid}.npz", members)
    refused(good, tmp_path, "dataset 'pulse_t'", "more than the", "bytes the member holds")


def test_a_corrupt_zlib_stream_in_an_npz_is_a_clean_refusal(good, session, pid, tmp_path):
    members = _as_npz(good, session, pid)
    path = good / "raw" / f"{pid}.npz"
    _npz(path, members)
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("grating_z.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    data[start + 200 : start + 232] = b"\xff" * 32  # inside the deflate stream, after the header
    path.write_bytes(bytes(data))
    refused(good, tmp_path, f"raw/{pid}.npz", "dataset 'grating_z'", "damaged")


def test_a_declared_huge_compressed_dataset_is_refused_by_its_shape(good, pid, tmp_path, no_reads):
    n = 3 * (1 << 30) // 8  # 3 GiB of zeros declared; HDF5 stores no chunk of them, the file stays small
    _swap(
        good, pid, "pulse_t", lambda g, name: g.create_dataset(name, (n,), "<f8", chunks=(1 << 16,), compression="gzip")
    )
    assert (good / "raw.h5").stat().st_size < 10 * MiB
    refused(good, tmp_path, f"/{pid}/pulse_t", f"declares {n * 8} bytes", "per array")


def test_the_session_limit_holds_the_arrays_together(good, pid, tmp_path, session):
    one = max(getattr(r, n).nbytes for r in session.raw.values() for n in ("grating_t", "grating_z", "pulse_t"))
    limits = RawLimits(max_array_bytes=one, max_session_bytes=2 * one)
    with pytest.raises(SessionFormatError, match=r"past the session's limit of \d+ bytes .* for all its arrays"):
        read_session(good, limits)
    assert read_session(good, RawLimits(max_array_bytes=one, max_session_bytes=100 * one)).points == session.points


def test_a_chunk_that_inflates_past_its_declared_size_is_refused(good, pid, tmp_path):
    """An 800 kB chunk stored as 65 kB of gzip that inflates to 64 MiB: HDF5 would allocate all of it; the check
    stops at 800 kB."""
    deflate = zlib.compressobj(9)
    bomb = b"".join(deflate.compress(bytes(MiB)) for _ in range(BOMB_BYTES // MiB)) + deflate.flush()

    def make(g, name):
        ds = g.create_dataset(name, (100_000,), "<f8", chunks=(100_000,), compression="gzip")
        ds.id.write_direct_chunk((0,), bomb)

    _swap(good, pid, "pulse_t", make)
    assert (good / "raw.h5").stat().st_size < MiB
    tracemalloc.start()
    try:
        with pytest.raises(SessionFormatError) as info:
            read_session(good)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert f"/{pid}/pulse_t" in str(info.value) and "inflates to more than its declared 800000 bytes" in str(info.value)
    assert peak < TRACED_PEAK, peak
    refused(good, tmp_path, "inflates to more than")


def test_a_stored_chunk_larger_than_its_declared_size_allows_is_refused_unread(good, pid, tmp_path):
    def make(g, name):
        ds = g.create_dataset(name, (1000,), "<f8", chunks=(1000,), compression="gzip")
        ds.id.write_direct_chunk((0,), os.urandom(64 << 10))  # 64 kB stored for an 8 kB chunk

    _swap(good, pid, "pulse_t", make)
    refused(good, tmp_path, f"/{pid}/pulse_t", "a stored chunk of 65536 bytes; at most 9055 for chunks of 8000 bytes")


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (lambda g, n: g.create_dataset(n, data=np.arange(5) + 1j), "dtype complex128; only a real numeric dtype"),
        (lambda g, n: g.create_dataset(n, data=["a", "b"], dtype=h5py.string_dtype()), "dtype object"),
        (lambda g, n: g.create_dataset(n, data=h5py.Empty("<f8")), "an empty dataset (no dataspace)"),
        (lambda g, n: g.create_dataset(n, data=np.zeros((3, 3))), "expected 1 dimension(s)"),
        (lambda g, n: g.create_dataset(n, data=np.zeros(3), compression="lzf"), "HDF5 filter(s) [32000]"),
        (lambda g, n: g.create_group(n), "not an expected dataset"),
    ],
    ids=["complex", "vlen-string", "empty", "2-D", "lzf", "group"],
)
def test_only_real_numeric_datasets_of_the_expected_form_are_read(good, pid, tmp_path, make, expected, no_reads):
    _swap(good, pid, "pulse_t", make)
    refused(good, tmp_path, "raw.h5", f"/{pid}/pulse_t", expected)


def test_an_unexpected_dataset_name_is_refused(good, pid, tmp_path, no_reads):
    with h5py.File(good / "raw.h5", "r+") as f:
        f[pid]["surprise"] = np.zeros(3)
    refused(good, tmp_path, f"/{pid}/surprise", "not an expected dataset (allowed: grating_t, grating_z, pulse_t")


def test_damaged_hdf5_files_are_clean_refusals(good, tmp_path):
    """Superblock, truncation and 40 byte-level corruptions (fixed seed): a SessionFormatError each time."""
    original = (good / "raw.h5").read_bytes()
    rng = np.random.default_rng(30)
    cases = [b"\0" * 8 + original[8:], original[: len(original) // 2]]
    for _ in range(40):
        data = bytearray(original)
        at = int(rng.integers(0, min(len(data), 4096)))  # the metadata lives at the start of the file
        data[at : at + 8] = rng.bytes(8)
        cases.append(bytes(data))
    for data in cases:
        (good / "raw.h5").write_bytes(data)
        try:
            read_session(good)  # a corruption of unused bytes may leave the file readable
        except SessionFormatError as exc:
            assert str(exc).startswith("raw.h5"), exc


# --- what the store and the panel read ----------------------------------------------------------------------


def test_the_stores_own_point_files_are_read_with_the_same_checks(tmp_path, session, pid):
    with SessionStore(tmp_path / "db.sqlite") as store:
        uid = store.create_session(session.station, "test")
        point = next(p for p in session.points if p.point_id == pid)
        store.add_point(uid, point, session.raw[pid])
        (path,) = (tmp_path / "db.sqlite.raw" / uid).glob("*.h5")
        with h5py.File(path, "r+") as f:
            del f["grating_t"]
            f["grating_t"] = h5py.ExternalLink("/etc/passwd", "/x")
        with pytest.raises(RawInputError, match="dataset '/grating_t': an external link"):
            store.load_session(uid).raw[pid]
    with pytest.raises(RawInputError, match="dataset '/grating_t': an external link"):
        read_point_file(path)


# --- leftovers of a killed writer --------------------------------------------------------------------------


def test_leftover_temporary_files_are_removed_at_the_next_open_of_the_store(tmp_path, session, pid, caplog):
    db = tmp_path / "db.sqlite"
    with SessionStore(db) as store:
        uid = store.create_session(session.station, "test")
        store.add_point(uid, session.points[0], session.raw[pid])
    raw_dir = tmp_path / "db.sqlite.raw"
    kept = sorted(p for p in raw_dir.rglob("*") if p.is_file())
    killed_run = raw_dir / uid / ".000001.h5.tmp"  # kill -9 while a point's file was written
    killed_run.write_bytes(b"\0" * 4096)
    killed_import = "20261206T000000-deadbeef"  # kill -9 after two raw files of an import, before its transaction
    (raw_dir / killed_import).mkdir()
    for name in ("000000.h5", ".000001.h5.tmp"):
        (raw_dir / killed_import / name).write_bytes(b"\0" * 4096)
    (raw_dir / f".import-{killed_import}.tmp").touch()
    live = raw_dir / uid / ".000002.h5.tmp"  # another process writing right now: locked, left alone
    fd = os.open(live, os.O_WRONLY | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        with caplog.at_level(logging.WARNING, logger="station.store"), SessionStore(db) as store:
            assert [s["uid"] for s in store.sessions()] == [uid]
            assert store.load_session(uid).raw[pid].pulse_t.size == session.raw[pid].pulse_t.size
        assert live.exists()
    finally:
        os.close(fd)
    assert not killed_run.exists() and not (raw_dir / killed_import).exists()
    assert not (raw_dir / f".import-{killed_import}.tmp").exists()
    assert sorted(p for p in raw_dir.rglob("*") if p.is_file() and p != live) == kept
    logged = caplog.text
    assert str(killed_run) in logged and f"removed {killed_import}, the raw files of an import" in logged
    live.unlink()


def test_a_finished_import_leaves_no_marker_and_keeps_its_files(tmp_path, good):
    db = tmp_path / "db.sqlite"
    assert main(["import", str(good), "--db", str(db)]) == 0
    raw_dir = tmp_path / "db.sqlite.raw"
    assert not list(raw_dir.glob(".*")) and len(list(raw_dir.rglob("*.h5"))) == 2
    with SessionStore(db) as store:
        (row,) = store.sessions()
        assert store.load_session(row["uid"]).raw
    assert len(list(raw_dir.rglob("*.h5"))) == 2
