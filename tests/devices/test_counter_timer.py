"""Counter/timer board: time-stamp unwrapping, window bookkeeping, and the real driver
against its emulator over a pty and a sim:// line, windows, crossings and pulse edges from the world.

Virtual clocks run faster than real time so that windows of tens to hundreds of
station seconds (and the 214.7 s wrap of the 32-bit tick counter) fit in a test.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.counter_timer import driver as ct
from drivers.errors import (
    ChecksumError,
    DeviceFault,
    DeviceTimeout,
    Disconnected,
    FrameError,
    LimitError,
)
from drivers.pty_link import Fault
from drivers.serial_port import TICK_S, TickUnwrapper, ticks_of

pytestmark = pytest.mark.timeout(60)

WRAP_S = 2**32 * TICK_S  # 214.748 s


class ManualClock:
    """A clock that moves only when told (for the pure unwrapping tests)."""

    def __init__(self, t_s: float = 0.0) -> None:
        self.t_s = t_s

    def now_s(self) -> float:
        return self.t_s

    def sleep_s(self, duration_s: float) -> None:
        self.t_s += duration_s


# ---------------------------------------------------------------- time stamps


def test_unwrap_across_wraps_and_long_gaps() -> None:
    clock = ManualClock(0.0)
    u = TickUnwrapper(clock)
    times = [0.0, 1.0, 200.0, 214.0, 215.0, 560.0, 561.0, 1500.0, 1500.5]
    got = []
    for t in times:
        clock.t_s = t + 0.3  # stamps arrive a little late
        got.append(u.unwrap_s(ticks_of(t)))
    assert np.allclose(got, times, atol=TICK_S)


def test_absolute_anchor_uses_the_clock() -> None:
    clock = ManualClock(1000.4)
    u = TickUnwrapper(clock, absolute=True)
    assert u.unwrap_s(ticks_of(1000.0)) == pytest.approx(1000.0, abs=TICK_S)
    rel = TickUnwrapper(ManualClock(1000.4))
    assert rel.unwrap_s(ticks_of(1000.0)) == pytest.approx(1000.0 - 4 * WRAP_S, abs=TICK_S)


def test_a_stream_read_late_keeps_its_stamps() -> None:
    """A host stall between starting a stream and reading it: 300 s of station time late is more than
    half a wrap (1.4 wraps at 1000x is 0.3 s of wall time). The first stamp is the first at or after
    the reset that preceded the command; each later one lies nearest its predecessor (a heartbeat
    stream), so the whole stream stays right, which the host-elapsed rule would not."""
    clock = ManualClock(5000.0)
    u = TickUnwrapper(clock, absolute=True, sequential=True)
    u.reset()  # the command that starts the stream goes out now
    stamps = 5000.2 + np.arange(0.0, 400.0, 0.7)  # stamped from 0.2 s on, heartbeats every 0.7 s
    clock.t_s = 5000.2 + 300.0  # the host reads the first one 300 s late, then the backlog
    got = [u.unwrap_s(ticks_of(t)) for t in stamps]
    assert np.allclose(got, stamps, atol=TICK_S)


def test_unwrap_array_across_a_wrap() -> None:
    clock = ManualClock(214.75)
    u = TickUnwrapper(clock, absolute=True)
    t = np.linspace(214.0, 215.5, 1001)
    raw = np.array([ticks_of(x) for x in t])
    assert raw[-1] < raw[0]  # it really wraps
    assert np.allclose(u.unwrap_array(raw) * TICK_S, t, atol=TICK_S)


def test_window_bookkeeping() -> None:
    w = ct.WindowResult(100, open_s=10.0, close_s=570.3, pulses=-100)
    w.crossings_s = np.array([10.05, 10.15, 570.25, 570.35])
    assert w.Tm_s == pytest.approx(560.3)
    assert w.t1_s == pytest.approx(0.05)
    assert w.Np == 3
    assert w.t2_s == pytest.approx(0.05)
    static = ct.WindowResult(100, open_s=1.0, close_s=2.0)
    assert static.t1_s is None and static.Np is None and static.t2_s is None


# ---------------------------------------------------------------- driver against emulator


def _check_against_world(emu, r: ct.WindowResult) -> None:
    """The driver's window is the one the world opened for the emulator's ARM."""
    w = emu.window
    assert r.open_s == pytest.approx(w.open_s, abs=TICK_S)
    assert r.close_s == pytest.approx(w.close_s, abs=TICK_S)
    assert r.pulses == w.pulses


def test_vibration_window(counter_rig) -> None:
    world, emu, board = counter_rig(speed=20.0, vibrate_hz=10.0)
    preset = 20_000
    board.arm(preset)
    r = board.wait_window()
    _check_against_world(emu, r)
    assert abs(r.pulses) == preset
    period = 0.1
    true = world.reference_crossings_s(emu.window.open_s, emu.window.close_s + period)
    assert r.Np is not None
    assert np.allclose(r.crossings_s, true[: r.Np + 1], atol=TICK_S)
    assert 0 < r.t1_s <= period + 1e-9
    assert 0 <= r.t2_s < period + 1e-9
    assert r.crossings_s[-2] < r.close_s <= r.crossings_s[-1]
    assert r.edges_t_s is None


def test_static_window_across_the_tick_wrap(counter_rig) -> None:
    """Table at rest, window of ~250 station s starting just before the 32-bit wrap."""
    world, emu, board = counter_rig(speed=250.0, vibrate_hz=0.0, start_s=100.0)
    rate_pps = _pulse_rate(world)
    preset = int(250 * rate_pps)
    r = board.measure(preset, timeout_s=30.0)
    _check_against_world(emu, r)
    assert r.open_s < WRAP_S < r.close_s  # the counter wrapped inside the window
    assert r.crossings_s.size == 0 and r.Np is None


def _pulse_rate(world) -> float:
    t = world.clock.now_s()
    edges, _ = world.pulse_edges_s(t, t + 1.0)
    return max(len(edges), 1) / 1.0


@pytest.mark.parametrize(
    ("vibrate_hz", "speed", "preset"),
    [(2.0, 2.0, 4000), (10.0, 1.0, 2000)],  # at 10 Hz (a = 12) the output reverses each period
)
def test_edge_stream(counter_rig, vibrate_hz, speed, preset) -> None:
    world, emu, board = counter_rig(speed=speed, vibrate_hz=vibrate_hz)
    r = board.measure(preset, stream_edges=True)
    _check_against_world(emu, r)
    assert r.edges_lost == 0
    w = emu.window
    # From just before the opening edge: the world models the table from the instant it is asked about,
    # and a sim:// line arms within a millisecond of the crank's command (not yet vibrating 1 ms earlier).
    all_t, all_d = world.pulse_edges_s(w.open_s - 1e-6, w.close_s + 1e-3)
    inside = (all_t > w.open_s + TICK_S / 2) & (all_t <= w.close_s + TICK_S / 2)
    true_t, true_d = all_t[inside], all_d[inside]
    assert r.edges_t_s is not None and r.edges_dir is not None
    assert len(r.edges_t_s) == len(true_t)
    assert np.allclose(r.edges_t_s, true_t, atol=TICK_S)
    assert np.array_equal(r.edges_dir, np.asarray(true_d, dtype=np.int8))
    # The world closes the window at |phi - phi_open| = P pulse angles: when the opening
    # edge goes against the precession, the level it opened on is crossed once more.
    opening_dir = int(all_d[np.argmin(np.abs(all_t - w.open_s))])
    sign = 1 if r.pulses > 0 else -1
    assert int(np.sum(r.edges_dir)) == r.pulses + (sign if opening_dir != sign else 0)
    assert np.any(r.edges_dir < 0) == (vibrate_hz == 10.0)
    assert r.edges_t_s[-1] == pytest.approx(r.close_s, abs=TICK_S)


@pytest.mark.parametrize("transport", ["pty"])  # a sim:// line paces in station time: 200x is not too fast there
def test_edge_stream_faster_than_the_line_drops_visibly(counter_rig) -> None:
    world, emu, board = counter_rig(speed=200.0, vibrate_hz=0.0)
    preset = int(100 * _pulse_rate(world))
    r = board.measure(preset, stream_edges=True, timeout_s=30.0)
    assert r.edges_lost > 0  # 200x real time cannot fit through 921600 baud
    assert r.edges_lost == emu.edges_dropped
    assert len(r.edges_t_s) + r.edges_lost == preset
    assert r.Tm_s > 0 and abs(r.pulses) == preset  # the window itself is intact


def test_preset_limits_and_busy(counter_rig) -> None:
    _, _, board = counter_rig(speed=1.0, vibrate_hz=0.0)
    for bad in (0, -5, 2**31):
        with pytest.raises(LimitError, match="preset_pulses"):
            board.arm(bad)
    board.arm(10_000_000)
    with pytest.raises(DeviceFault, match="busy"):
        board.arm(10)
    assert board.status()["state"] in ("armed", "counting")
    board.abort()
    assert board.status()["state"] == "idle"


def test_counter_overflow_fault(counter_rig) -> None:
    _, emu, board = counter_rig(speed=1.0, vibrate_hz=0.0)
    emu.inject(Fault.COUNTER_OVERFLOW)
    t0 = time.monotonic()
    with pytest.raises(DeviceFault, match="overflow") as info:
        board.measure(10_000_000)
    assert info.value.field == "pulse_count"
    assert time.monotonic() - t0 < 1.0
    assert board.status()["fault"] == "counter overflow"


def test_arm_is_not_retried_but_status_is(counter_rig) -> None:
    _, emu, board = counter_rig(speed=1.0, vibrate_hz=0.0)
    emu.inject(Fault.NO_ANSWER, count=1)
    with pytest.raises(DeviceTimeout, match="ARM"):
        board.arm(1000)
    assert board.status()["state"] == "idle"  # the ARM was lost, not repeated
    emu.inject(Fault.NO_ANSWER, count=2)
    assert board.status()["state"] == "idle"  # third attempt answered
    emu.inject(Fault.NO_ANSWER, count=None)
    with pytest.raises(DeviceTimeout, match="after 3 attempts"):
        board.status()


@pytest.mark.parametrize(
    ("fault", "error"),
    [(Fault.CRC_ERROR, ChecksumError), (Fault.GARBLE, FrameError), (Fault.TRUNCATE, FrameError)],
)
def test_damaged_event_fails_the_window(counter_rig, fault, error) -> None:
    _, emu, board = counter_rig(speed=1.0, vibrate_hz=10.0)
    board.arm(10_000_000)
    ev = board.next_event()
    while ev.kind != "open":
        ev = board.next_event()
    emu.inject(fault)
    with pytest.raises(error):
        board.wait_window(timeout_s=5.0)
    board.abort()


def test_silent_board_times_out(counter_rig) -> None:
    _, emu, board = counter_rig(speed=1.0, vibrate_hz=0.0)
    board.arm(10_000_000)
    emu.inject(Fault.NO_ANSWER, count=None)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="silent"):
        board.wait_window()
    assert time.monotonic() - t0 < board.silence_s + 1.0


def test_disconnect_mid_window(counter_rig) -> None:
    _, emu, board = counter_rig(speed=1.0, vibrate_hz=10.0)
    board.arm(10_000_000)
    board.next_event()
    emu.inject(Fault.DISCONNECT)
    with pytest.raises(Disconnected):
        board.wait_window(timeout_s=5.0)
    board.close()
