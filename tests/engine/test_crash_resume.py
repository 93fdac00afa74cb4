"""kill -9 of a running session, then `station resume`: every finished point survives, none is measured twice."""

from __future__ import annotations

import os
import re
import signal
import sqlite3
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.timeout(180)

PROCEDURE = """\
procedure = "integral_precession"
[params]
positions_deg = [0, 72, 144, 216, 288]
freqs_hz = [10]
window_s = 30
settle_s = 2
"""


def _points(db) -> list[tuple[str, int]]:
    try:
        with sqlite3.connect(db) as con:
            return con.execute("SELECT point_id, sequence FROM points ORDER BY sequence").fetchall()
    except sqlite3.OperationalError:  # the child has not created its tables yet
        return []


def test_kill_9_mid_session_then_resume(tmp_path) -> None:
    proc_file = tmp_path / "quick.toml"
    proc_file.write_text(PROCEDURE)
    db = tmp_path / "station.sqlite"
    cmd = [sys.executable, "-m", "station.cli.cli", "run", str(proc_file), "--out", str(tmp_path), "--speed", "200"]
    child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.monotonic()
        while not (db.exists() and len(_points(db)) >= 4):
            assert child.poll() is None, "the session ended before it could be killed"
            assert time.monotonic() - t0 < 90, "no points were stored"
            time.sleep(0.05)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    stored = _points(db)
    assert [s for _, s in stored] == list(range(len(stored)))
    with sqlite3.connect(db) as con:
        ((uid, status),) = con.execute("SELECT uid, status FROM sessions").fetchall()
    assert status == "running"  # as the kill left it: neither finished nor failed

    done = subprocess.run(
        [sys.executable, "-m", "station.cli.cli", "resume", uid, "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=150,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    after = _points(db)
    assert after[: len(stored)] == stored  # the finished points, untouched
    assert [s for _, s in after] == list(range(10)) and len({p for p, _ in after}) == 10
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT status FROM sessions").fetchone() == ("finished",)
    assert re.search(r"^integral:", done.stdout, re.M) and re.search(r"^\s+kz\s+= ", done.stdout, re.M)  # analysed
