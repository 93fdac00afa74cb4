"""Signals on `station run` with bluesky's semantics, through the real CLI in a child process: the first Ctrl-C
pauses at the next safe point and asks, an answer resumes, a second Ctrl-C aborts, SIGTERM aborts; every way
ends with a resumable session marked `aborted`, every finished point kept, no traceback. A second process on a
session that is being run gets a clear refusal.

Bounds: a pause takes effect before the next measurement: one 30 s window at 200x is 0.15 s of wall time, so
5 s with the start-up of a loaded machine; an abort ends within the supervisor's grace (ABORT_GRACE_S).
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from station.engine.supervisor import ABORT_GRACE_S

from .test_crash_resume import PROCEDURE  # the same quick session

pytestmark = pytest.mark.timeout(180)

PAUSE_BOUND_S = 5.0


def _query(db: Path, sql: str) -> list[tuple]:
    try:
        with sqlite3.connect(db) as con:
            return con.execute(sql).fetchall()
    except sqlite3.OperationalError:  # the child has not made its tables yet
        return []


def _wait(predicate, timeout_s: float, child: subprocess.Popen | None = None) -> None:
    t0 = time.monotonic()
    while not predicate():
        if child is not None and child.poll() is not None:
            out, err = child.communicate()
            raise AssertionError(f"the run ended too early: {out[-2000:]}{err[-2000:]}")
        assert time.monotonic() - t0 < timeout_s, f"not within {timeout_s} s"
        time.sleep(0.05)


def _start(tmp_path: Path, speed: float = 200.0) -> tuple[subprocess.Popen, Path]:
    proc_file = tmp_path / "quick.toml"
    proc_file.write_text(PROCEDURE)
    cmd = [
        sys.executable,
        "-m",
        "station.cli.cli",
        "run",
        str(proc_file),
        "--out",
        str(tmp_path),
        "--speed",
        str(speed),
    ]
    child = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return child, tmp_path / "station.sqlite"


def _points(db: Path) -> int:
    return len(_query(db, "SELECT id FROM points"))


def _states(db: Path) -> list[str]:
    return [m for (m,) in _query(db, "SELECT message FROM events WHERE kind = 'state' ORDER BY id")]


def test_ctrl_c_pauses_and_asks_an_answer_resumes_a_second_ctrl_c_aborts(tmp_path) -> None:
    child, db = _start(tmp_path)
    try:
        _wait(lambda: _points(db) >= 2, 90, child)
        child.send_signal(signal.SIGINT)
        _wait(lambda: "paused" in _states(db), PAUSE_BOUND_S, child)
        held = _points(db)
        time.sleep(0.5)
        assert _points(db) == held  # nothing is measured while paused
        child.stdin.write("r\n")
        child.stdin.flush()
        _wait(lambda: _points(db) > held, 30, child)
        child.send_signal(signal.SIGINT)  # pauses again (the answer reset the count) ...
        time.sleep(0.05)
        child.send_signal(signal.SIGINT)  # ... and the second one aborts
        out, err = child.communicate(timeout=ABORT_GRACE_S + 60)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 1, out + err
    assert "Traceback" not in err and "Traceback" not in out
    assert "second Ctrl-C: aborting" in err
    ((uid, status),) = _query(db, "SELECT uid, status FROM sessions")
    assert status == "aborted" and "aborted" in _states(db)
    seqs = [s for (s,) in _query(db, "SELECT sequence FROM points ORDER BY sequence")]
    assert seqs == list(range(len(seqs))) and len(seqs) < 10
    # resumable: the rest is measured, nothing twice
    done = subprocess.run([sys.executable, "-m", "station.cli.cli", "resume", uid, "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=150)  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert [s for (s,) in _query(db, "SELECT sequence FROM points ORDER BY sequence")] == list(range(10))


NESTED_CTRL_C = """
import io, os, signal, threading, time
from types import SimpleNamespace
from station.cli.signals import RunSignals
from station.engine.runner import State

held = threading.Lock()  # the engine's lock, as pause and abort take it
calls = []

class Controller:
    engine = SimpleNamespace(progress=SimpleNamespace(state=State.RUNNING))

    def pause(self):
        with held:
            calls.append("pause")
            os.kill(os.getpid(), signal.SIGINT)  # the second Ctrl-C comes while the first is in here
            time.sleep(0.3)

    def abort(self):
        got = held.acquire(timeout=2.0)  # in a handler nested in the first one's pause: never got
        calls.append("abort" if got else "deadlock")
        if got:
            held.release()

with RunSignals(Controller(), ask=lambda prompt: "a", out=io.StringIO()):
    os.kill(os.getpid(), signal.SIGINT)
    t0 = time.monotonic()
    while len(calls) < 2 and time.monotonic() - t0 < 10.0:
        time.sleep(0.01)
print(calls)
"""


def test_a_second_ctrl_c_while_the_first_is_being_handled_aborts_without_deadlock() -> None:
    """A signal handler runs between two bytecodes of the main thread, inside another handler too: one that takes
    the engine's lock can wait forever on its own thread. The handlers only queue; a thread of their own calls the
    controller, one signal after the other (in a child: signal handlers belong to a main thread)."""
    done = subprocess.run([sys.executable, "-c", NESTED_CTRL_C], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "['pause', 'abort']", done.stdout + done.stderr


def test_sigterm_aborts_cleanly_and_a_second_process_is_refused(tmp_path) -> None:
    child, db = _start(tmp_path, speed=20.0)  # 36 s of wall time: long enough for a second process to start
    try:
        _wait(lambda: _points(db) >= 1, 90, child)
        ((uid,),) = _query(db, "SELECT uid FROM sessions")
        second = subprocess.run([sys.executable, "-m", "station.cli.cli", "resume", uid, "--out", str(tmp_path)],
                                capture_output=True, text=True, timeout=120)  # fmt: skip
        assert second.returncode == 2
        assert f"session {uid} is being run by another process" in second.stderr
        assert f'"pid": {child.pid}' in second.stderr
        t0 = time.monotonic()
        child.send_signal(signal.SIGTERM)
        _, err = child.communicate(timeout=ABORT_GRACE_S + 60)
        took_s = time.monotonic() - t0
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 1 and "Traceback" not in err, err
    assert "SIGTERM: aborting" in err and took_s < ABORT_GRACE_S + 30
    assert _query(db, "SELECT status FROM sessions") == [("aborted",)]


def test_a_session_left_running_by_kill_9_is_found_interrupted_and_listed(tmp_path) -> None:
    child, db = _start(tmp_path)
    try:
        _wait(lambda: _points(db) >= 2, 90, child)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.communicate()
    assert _query(db, "SELECT status FROM sessions") == [("running",)]
    listed = subprocess.run([sys.executable, "-m", "station.cli.cli", "sessions", "--db", str(db)], capture_output=True,
                            text=True, timeout=60)  # fmt: skip
    assert listed.returncode == 0 and " interrupted " in listed.stdout, listed.stdout + listed.stderr
    ((uid,),) = _query(db, "SELECT uid FROM sessions")
    exported = subprocess.run([sys.executable, "-m", "station.cli.cli", "export", uid, str(tmp_path / "x"), "--db",
    str(db)],
                              capture_output=True, text=True, timeout=60)  # fmt: skip
    assert exported.returncode == 0, exported.stderr
