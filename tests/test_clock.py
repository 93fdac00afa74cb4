"""The clock API (station/clock.py) on both of today's clocks: waits and timers count the clock's seconds.

Every assertion is made in the clock's own seconds, never in wall seconds: a busy
host may make any wait last longer, never shorter.
"""

from __future__ import annotations

import threading

import pytest

from station.clock import Clock, VirtualClock, WallClock, host_clock

SPEED = 200.0  # a VirtualClock this fast makes 1 station second 5 ms of wall time


@pytest.fixture(params=["wall", "virtual"])
def clock(request: pytest.FixtureRequest) -> Clock:
    return WallClock() if request.param == "wall" else VirtualClock(SPEED)


def _scale(clock: Clock) -> float:
    """Station seconds that last about 20 ms of wall time on this clock."""
    return 0.02 / clock.link_s(1.0)


def test_an_event_wait_times_out_after_its_station_seconds(clock: Clock) -> None:
    ev = clock.event()
    timeout_s = _scale(clock)
    t0 = clock.now_s()
    assert ev.wait(timeout_s=timeout_s) is False
    assert clock.now_s() - t0 >= timeout_s


def test_an_event_set_from_another_thread_ends_the_wait(clock: Clock) -> None:
    ev = clock.event()
    threading.Thread(target=ev.set).start()
    assert ev.wait(timeout_s=1000 * _scale(clock)) is True
    assert ev.is_set()
    ev.clear()
    assert not ev.is_set()


def test_condition_wait_for_returns_the_predicate_or_times_out(clock: Clock) -> None:
    cond = clock.condition()
    box: list[int] = []

    def put() -> None:
        with cond:
            box.append(1)
            cond.notify_all()

    threading.Thread(target=put).start()
    with cond:
        assert cond.wait_for(lambda: box, timeout_s=1000 * _scale(clock)) == [1]
        t0 = clock.now_s()
        assert cond.wait_for(lambda: len(box) > 1, timeout_s=_scale(clock)) is False
        assert clock.now_s() - t0 >= _scale(clock)


def test_sleep_lasts_its_station_seconds(clock: Clock) -> None:
    t0 = clock.now_s()
    clock.sleep_s(_scale(clock))
    assert clock.now_s() - t0 >= _scale(clock)


def test_timers_due_at_the_same_instant_run_in_the_order_they_were_made(clock: Clock) -> None:
    ran: list[int] = []
    done = clock.event()
    due_s = clock.now_s() + _scale(clock)
    for i in range(5):
        clock.call_at(due_s, lambda i=i: ran.append(i))
    clock.call_at(due_s, done.set)
    assert done.wait(timeout_s=1000 * _scale(clock))
    assert ran == [0, 1, 2, 3, 4]
    assert clock.now_s() >= due_s


def test_a_timer_runs_at_its_time_and_a_cancelled_one_never(clock: Clock) -> None:
    seen_s: list[float] = []
    done = clock.event()
    due_s = clock.now_s() + _scale(clock)
    cancelled = clock.call_at(due_s, lambda: seen_s.append(-1.0))
    clock.call_at(due_s, lambda: seen_s.append(clock.now_s()))
    cancelled.cancel()
    clock.call_at(due_s + _scale(clock), done.set)
    assert done.wait(timeout_s=1000 * _scale(clock))
    assert len(seen_s) == 1 and seen_s[0] >= due_s


def test_call_every_keeps_to_its_grid_until_cancelled(clock: Clock) -> None:
    period_s = _scale(clock) / 2
    ticks_s: list[float] = []
    enough = clock.event()
    t0 = clock.now_s()

    def tick() -> None:
        ticks_s.append(clock.now_s())
        if len(ticks_s) == 4:
            enough.set()

    handle = clock.call_every(period_s, tick)
    assert enough.wait(timeout_s=1000 * _scale(clock))
    handle.cancel()
    n = len(ticks_s)
    clock.sleep_s(4 * period_s)
    assert len(ticks_s) <= n + 1  # at most the one already running when cancelled
    # the k-th tick is never before t0 + k periods (a busy host may make it late, never early)
    assert all(t >= t0 + (k + 1) * period_s for k, t in enumerate(ticks_s[:4]))


def test_a_failing_timer_does_not_stop_the_others(clock: Clock) -> None:
    done = clock.event()

    def fail() -> None:
        raise RuntimeError("boom")

    clock.call_at(clock.now_s(), fail)
    clock.call_at(clock.now_s() + _scale(clock), done.set)
    assert done.wait(timeout_s=1000 * _scale(clock))


def test_call_every_refuses_a_period_that_is_not_positive() -> None:
    with pytest.raises(ValueError, match="period_s"):
        WallClock().call_every(0.0, lambda: None)


def test_the_link_of_a_wall_clock_is_itself_and_of_a_paced_virtual_clock_the_host() -> None:
    """A paced VirtualClock times its links in wall seconds: a host thread cannot answer a 0.5 s timeout in
    0.5 ms of wall time at 1000x (station/clock.py)."""
    wall = WallClock()
    assert wall.link is wall
    assert VirtualClock(1000.0).link is host_clock()


def test_advance_moves_a_timer_due_in_the_far_future_to_now() -> None:
    clock = VirtualClock(1.0)
    done = clock.event()
    clock.call_at(clock.now_s() + 3600.0, done.set)
    clock.advance_s(3600.0)
    assert done.wait(timeout_s=10.0)
