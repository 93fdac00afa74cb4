"""Raw streams in HDF5: the store keeps one chunked, compressed file per point beside its SQLite file, the
interchange one raw.h5 with a group per point; both read a point only when asked; `station simulate --raw`
streams point by point with progress on stderr."""

import h5py
import numpy as np
import pytest

import station.cli.cli
from station.cli.cli import main
from station.interchange import content_hash, read_session, write_session
from station.rawfile import CHUNK, LazyRaw
from station.store import SessionStore, StoreError
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session


@pytest.fixture(scope="module")
def session():
    return simulate_session(multiposition_plan([0.0, 180.0], [10.0], window_s=8.0), TwinConfig(), seed=2, raw=True)


def _equal(a, b) -> None:
    for name in ("grating_t", "grating_z", "pulse_t", "pulse_dir", "reference_t"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype
            np.testing.assert_array_equal(x, y)


def test_the_store_keeps_each_points_raw_streams_in_a_compressed_hdf5_file(tmp_path, session):
    with SessionStore(tmp_path / "db.sqlite") as store:
        uid = store.create_session(session.station, "test")
        for p in session.points:
            store.add_point(uid, p, session.raw.get(p.point_id))
        files = sorted((tmp_path / "db.sqlite.raw" / uid).glob("*.h5"))
        assert len(files) == len(session.raw) and not list((tmp_path / "db.sqlite.raw" / uid).glob(".*"))
        with h5py.File(files[0], "r") as f:
            ds = f["pulse_t"]
            assert ds.compression == "gzip" and ds.shuffle and ds.chunks[0] == min(CHUNK, ds.size)
        back = store.load_session(uid)
        assert isinstance(back.raw, LazyRaw) and sorted(back.raw) == sorted(session.raw)
        for pid in session.raw:
            _equal(back.raw[pid], session.raw[pid])
        # a second try of a stored point is refused before it can touch the stored file
        pid = next(iter(session.raw))
        point = next(p for p in session.points if p.point_id == pid)
        before = files[0].read_bytes()
        with pytest.raises(StoreError, match="already stored"):
            store.add_point(uid, point, session.raw[pid])
        assert files[0].read_bytes() == before
        assert store.load_session(uid, with_raw=False).raw == {}


def test_raw_h5_round_trip_and_import_stream_point_by_point(tmp_path, session):
    d = write_session(session, tmp_path / "s")
    with h5py.File(d / "raw.h5", "r") as f:
        assert sorted(f) == sorted(session.raw)
    back = read_session(d)
    assert isinstance(back.raw, LazyRaw) and content_hash(back) == content_hash(session)
    with SessionStore(tmp_path / "db.sqlite") as store:
        uid, created = store.import_session(back, content_hash(back))
        assert created
        stored = store.load_session(uid)
        for pid in session.raw:
            _equal(stored.raw[pid], session.raw[pid])


def test_a_refused_import_leaves_no_raw_files(tmp_path, session):
    d = write_session(session, tmp_path / "s")
    back = read_session(d)
    with SessionStore(tmp_path / "db.sqlite") as store:
        uid = store.create_session(session.station, "test")
        store.add_point(uid, session.points[0])
        dup = type(back)(back.station, [*back.points, back.points[0]], raw=back.raw)  # the store refuses the copy
        with pytest.raises(StoreError, match="nothing stored"):
            store.import_session(dup, "x" * 64)
        assert len(store.sessions()) == 1
    leftovers = [p for p in (tmp_path / "db.sqlite.raw").iterdir() if p.name != uid] if (
        tmp_path / "db.sqlite.raw").exists() else []  # fmt: skip
    assert leftovers == []


def test_simulate_raw_streams_with_progress(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(station.cli.cli, "seed000_plan", lambda: multiposition_plan([0.0, 180.0], [10.0], window_s=5.0))
    out = tmp_path / "sim"
    assert main(["simulate", str(out), "--raw"]) == 0
    err = capsys.readouterr().err
    assert "simulate" in err and "4/4" in err  # a vibration and a static point at each position, on stderr
    s = read_session(out)
    assert len(s.points) == 4 and sorted(s.raw) == sorted(p.point_id for p in s.points)
    assert s.provenance["simulated"] is True and s.provenance["station_id"] == "twin"
