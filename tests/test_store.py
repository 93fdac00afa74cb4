"""The session store: exact round trip, no duplicated points, and kill -9 loses no finished point."""

import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from station.store import SessionStore, StoreError
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session


def test_round_trip_with_raw(tmp_path):
    s = simulate_session(multiposition_plan([0.0], [10.0], window_s=5.0), TwinConfig(), seed=3, raw=True)
    with SessionStore(tmp_path / "db.sqlite") as store:
        uid = store.create_session(s.station, "test")
        for p in s.points:
            store.add_point(uid, p, s.raw[p.point_id])
        back = store.load_session(uid)
    assert back.points == s.points
    for pid, raw in s.raw.items():
        np.testing.assert_array_equal(back.raw[pid].pulse_t, raw.pulse_t)
        np.testing.assert_array_equal(back.raw[pid].pulse_dir, raw.pulse_dir)


def test_a_point_is_never_stored_twice(tmp_path):
    s = simulate_session(multiposition_plan([0.0], [10.0], window_s=5.0), TwinConfig(), seed=3)
    with SessionStore(tmp_path / "db.sqlite") as store:
        uid = store.create_session(s.station, "test")
        store.add_point(uid, s.points[0])
        with pytest.raises(StoreError, match="already stored"):
            store.add_point(uid, s.points[0])
        assert len(store.load_session(uid).points) == 1


WRITER = textwrap.dedent(
    """
    import sys
    import numpy as np
    from station.store import SessionStore
    from station.session import PointRecord, RawStreams, StationInfo
    store = SessionStore(sys.argv[1])
    uid = store.create_session(StationInfo(), "crash-test")
    print(uid, flush=True)
    rng = np.random.default_rng(0)
    for i in range(100000):
        p = PointRecord(f"P{i:05d}", i, float(i), 0.0, 0.0, "static", 819200, 560.0 + i)
        raw = RawStreams(rng.random(20000), rng.random(20000), rng.random(50000))
        store.add_point(uid, p, raw)
        print(i, flush=True)  # reported only once the point's transaction has committed
    """
)


@pytest.mark.parametrize("kill_after", [3, 17])
def test_kill_9_loses_no_finished_point(tmp_path, kill_after):
    db = tmp_path / "db.sqlite"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(db)], stdout=subprocess.PIPE, text=True)
    uid = proc.stdout.readline().strip()
    finished = -1
    while finished < kill_after:
        finished = int(proc.stdout.readline())
    os.kill(proc.pid, signal.SIGKILL)  # possibly in the middle of the next point's transaction
    proc.wait()
    with SessionStore(db) as store:
        points = store.load_session(uid).points
    assert len(points) >= finished + 1
    assert [p.sequence for p in points] == list(range(len(points)))  # no gap, no half point
    with SessionStore(db) as store:
        raws = store.load_session(uid).raw
    assert all(r.grating_t.size == 20000 and r.pulse_t.size == 50000 for r in raws.values())
