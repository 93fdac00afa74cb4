"""Every wait of the production code goes through the station clock (station/clock.py).

Reads the syntax trees of every production module and fails on a new way of
waiting or timing that bypasses the clock:

- a call of `time.sleep`, `time.monotonic`, `time.monotonic_ns`, `time.time`,
  `time.perf_counter` (or the same names imported from `time`);
- a wait with a timeout on a bare threading or queue object, or a library's own
  wall-clock wait: a call of `wait`, `wait_for`, `get`, `join`, `acquire` or `put`
  whose timeout is passed as `timeout=` or in its threading/queue position, or of
  `wait_for_heartbeat`;
- `select.select`, `select.poll` or a `.poll(...)` with an argument.

The clock's own objects take `timeout_s=` by keyword, so the test can tell them
apart without knowing types. Waits without a timeout (`event.wait()`) are not
time: they are allowed. The allow-list below is short, and each entry says why
it must stay.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PRODUCTION = ("station", "drivers", "procedures", "web")
TIME_CALLS = {"sleep", "monotonic", "monotonic_ns", "time", "perf_counter", "perf_counter_ns"}
TIMED_WAITS = {"wait", "wait_for", "get", "join", "acquire", "put"}

# (file, what) -> why it must stay
ALLOWED: dict[tuple[str, str], str] = {
    ("station/clock.py", "*"): "the clock itself: the one place that reads the wall clock and waits on threads",
    ("station/event_clock.py", "*"): "the discrete-event clock: its parties block on its own condition, and "
    "its optional ceiling paces it against the wall clock",
    ("drivers/pty_link.py", "select.select"): "the real-transport edge: an emulator serving a pseudo-terminal "
    "waits on its file descriptor (the wait's length comes from the link clock)",
    ("station/cli/control.py", ".poll"): "the real-transport edge: the zmq control channel's poller "
    "(its timeout is the socket's, not a wait of the station)",
    ("station/telemetry.py", "time.time"): "a UTC time stamp on each telemetry message for the people watching "
    "(not a duration)",
    ("web/relay.py", "time.time"): "UTC time stamps of the messages a station relays to the panel (not durations)",
    ("station/engine/runner.py", "time.perf_counter"): "the wall time a session took, recorded as its event "
    "(a measurement of the host, not a wait)",
    ("station/cli/console.py", "time.perf_counter"): "the wall time the console prints for a session and its analysis "
    "(a measurement of the host, not a wait)",
    ("station/central/sync.py", "time.perf_counter"): "the wall time a sync took, in its report "
    "(a measurement of the host)",
    (
        "station/gap/api.py",
        "time.perf_counter",
    ): "the CPU/wall cost of a diagnosis in its result (a measurement of the host)",
    ("station/gap/validate.py", "time.perf_counter"): "the wall time of a validation in its result (a measurement)",
}


def _violations(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(), str(path))
    from_time = {
        alias.asname or alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and node.module == "time"
        for alias in node.names
        if alias.name in TIME_CALLS
    }
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Name) and f.id in from_time:
            found.append((node.lineno, f"time.{f.id}"))
        if not isinstance(f, ast.Attribute):
            continue
        owner = f.value.id if isinstance(f.value, ast.Name) else None
        if owner == "time" and f.attr in TIME_CALLS:
            found.append((node.lineno, f"time.{f.attr}"))
        elif owner == "select" and f.attr in ("select", "poll", "epoll"):
            found.append((node.lineno, f"select.{f.attr}"))
        elif f.attr == "wait_for_heartbeat":
            found.append((node.lineno, ".wait_for_heartbeat"))
        elif f.attr == "poll" and (node.args or node.keywords):
            found.append((node.lineno, ".poll"))
        elif f.attr in TIMED_WAITS and _has_timeout(node):
            found.append((node.lineno, f".{f.attr}"))
    return found


def _has_timeout(call: ast.Call) -> bool:
    """threading/queue signatures: wait(timeout), wait_for(pred, timeout), join(timeout),
    get(block, timeout), acquire(blocking, timeout), put(item, block, timeout)."""
    f = call.func
    assert isinstance(f, ast.Attribute)
    if any(k.arg == "timeout" for k in call.keywords):
        return True
    args = call.args
    if f.attr == "wait":
        return bool(args)
    if f.attr == "wait_for":
        return len(args) >= 2
    if f.attr == "join":  # str.join(parts) too: only a number is a timeout
        return bool(args) and isinstance(args[0], ast.Constant) and isinstance(args[0].value, int | float)
    block_at = 1 if f.attr == "put" else 0
    return (
        len(args) > block_at + 1 and isinstance(args[block_at], ast.Constant) and isinstance(args[block_at].value, bool)
    )


def _production_files() -> list[Path]:
    return sorted(p for pkg in PRODUCTION for p in (ROOT / pkg).rglob("*.py"))


def test_no_wait_or_time_reading_bypasses_the_clock() -> None:
    bad = []
    for path in _production_files():
        rel = path.relative_to(ROOT).as_posix()
        if (rel, "*") in ALLOWED:
            continue
        for line, what in _violations(path):
            if (rel, what) not in ALLOWED:
                bad.append(f"{rel}:{line}: {what}")
    assert not bad, "waits or time readings outside the station clock:\n" + "\n".join(bad)


def test_every_allowed_entry_is_still_needed() -> None:
    """An entry whose file no longer does what it allows is dead and goes."""
    used = set()
    for path in _production_files():
        rel = path.relative_to(ROOT).as_posix()
        used.update((rel, what) for _, what in _violations(path))
    stale = [key for key in ALLOWED if key[1] != "*" and key not in used]
    assert not stale, f"allow-list entries no longer needed: {stale}"


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("import time\ntime.sleep(1)", ["time.sleep"]),
        ("from time import monotonic as m\nm()", ["time.m"]),
        ("ev.wait(0.5)", [".wait"]),
        ("q.get(timeout=t)", [".get"]),
        ("th.join(timeout=1.0)", [".join"]),
        ("node.nmt.wait_for_heartbeat(timeout=t)", [".wait_for_heartbeat"]),
        ("import select\nselect.select([fd], [], [], 0.1)", ["select.select"]),
        (
            "q.get(True, 0.5)\nlock.acquire(True, t)\ncond.wait_for(ready, t)\nev.wait(t)",
            [".get", ".acquire", ".wait_for", ".wait"],
        ),
        ("ev.wait()\nev.wait(timeout_s=0.5)\n', '.join(parts)\nd.get('k', 0)\nq.put(item)", []),
    ],
)
def test_the_reader_tells_clock_waits_from_bare_ones(tmp_path: Path, source: str, expected: list[str]) -> None:
    """The checker itself: bare waits found, the clock's keyword waits and non-waits left alone."""
    f = tmp_path / "m.py"
    f.write_text(source)
    assert [what for _, what in _violations(f)] == expected
