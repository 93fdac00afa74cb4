"""The discrete-event clock (station/event_clock.py): time moves only when every party waits.

Station times are compared exactly (to the last bit where the arithmetic is the
same): nothing here depends on how fast the host runs, which is the point.
"""

from __future__ import annotations

import threading

import pytest
from busy import busy_loops

from station.clock import Clock, spawn_party
from station.event_clock import PACE_STEP_WALL_S, ClockDeadlockError, EventClock, Pacemaker


def test_it_implements_the_station_clock_and_is_its_own_link() -> None:
    clock = EventClock()
    assert isinstance(clock, Clock)
    assert clock.link is clock


def test_a_sleep_jumps_to_its_end_exactly() -> None:
    clock = EventClock(start_s=10.0)
    clock.sleep_s(3600.0)
    assert clock.now_s() == 3610.0


def test_time_stands_still_while_a_party_works() -> None:
    clock = EventClock()
    seen: dict[str, float] = {}
    go = threading.Event()

    def sleeper() -> None:
        clock.sleep_s(5.0)
        seen["woke"] = clock.now_s()

    def worker() -> None:
        seen["before"] = clock.now_s()
        go.wait()  # plain wall-time work: the clock must not move meanwhile
        seen["after"] = clock.now_s()
        clock.sleep_s(1.0)
        seen["worker_woke"] = clock.now_s()

    threading.Timer(0.05, go.set).start()  # the worker's wall-time work ends after 50 ms, not a party
    with clock.party("main"):
        a = spawn_party(clock, "sleeper", sleeper)
        b = spawn_party(clock, "worker", worker)
        clock.sleep_s(0.5)  # main waits; while the worker works, time stays at 0
        assert clock.now_s() == 0.5
    a.join()
    b.join()
    assert seen == {"before": 0.0, "after": 0.0, "woke": 5.0, "worker_woke": 1.0}


def test_timers_at_one_instant_run_in_creation_order_in_the_waiting_thread() -> None:
    clock = EventClock()
    ran: list[tuple[int, str]] = []
    for i in range(4):
        clock.call_at(2.0, lambda i=i: ran.append((i, threading.current_thread().name)))
    cancelled = clock.call_at(2.0, lambda: ran.append((-1, "")))
    cancelled.cancel()
    clock.sleep_s(3.0)
    me = threading.current_thread().name
    assert ran == [(0, me), (1, me), (2, me), (3, me)]


def test_call_every_ticks_on_its_grid() -> None:
    clock = EventClock()
    ticks: list[float] = []
    handle = clock.call_every(0.25, lambda: ticks.append(clock.now_s()))
    clock.sleep_s(1.0)
    handle.cancel()
    clock.sleep_s(1.0)
    assert ticks == [0.25, 0.5, 0.75, 1.0]


def test_an_event_ends_a_wait_at_the_instant_it_is_set() -> None:
    clock = EventClock()
    ev = clock.event()
    woke: list[tuple[bool, float]] = []

    def waiter() -> None:
        woke.append((ev.wait(timeout_s=100.0), clock.now_s()))
        woke.append((ev.wait(timeout_s=0.0), clock.now_s()))

    with clock.party("setter"):
        t = spawn_party(clock, "waiter", waiter)
        clock.sleep_s(7.0)
        ev.set()
    t.join()
    assert woke == [(True, 7.0), (True, 7.0)]
    ev.clear()
    t0 = clock.now_s()
    assert ev.wait(timeout_s=2.5) is False
    assert clock.now_s() == t0 + 2.5


def test_a_condition_hands_off_between_parties_in_station_time() -> None:
    clock = EventClock()
    cond = clock.condition()
    box: list[float] = []
    got: list[float] = []

    def consumer() -> None:
        for _ in range(3):
            with cond:
                assert cond.wait_for(lambda: box, timeout_s=60.0)
                got.append(box.pop())
                cond.notify_all()

    with clock.party("producer"):
        t = spawn_party(clock, "consumer", consumer)
        for _ in range(3):
            clock.sleep_s(1.5)
            with cond:
                box.append(clock.now_s())
                cond.notify_all()
                assert cond.wait_for(lambda: not box, timeout_s=60.0)
    t.join()
    assert got == [1.5, 3.0, 4.5]


def test_a_wait_that_can_never_end_names_every_party_and_what_it_waits_on() -> None:
    clock = EventClock()
    never = clock.event()
    errors: list[BaseException] = []

    def stuck() -> None:
        try:
            never.wait()
        except ClockDeadlockError as exc:
            errors.append(exc)

    with clock.party("engine"):
        t = spawn_party(clock, "servo-link", stuck)
        with pytest.raises(ClockDeadlockError) as info:
            clock.event().wait()
        never.set()
    t.join()
    message = str(info.value)
    assert "engine" in message and "servo-link" in message and "event" in message


def test_without_parties_only_a_timed_wait_moves_time() -> None:
    """A thread that waits for a run's end without a deadline must not drive the station on by itself:
    with no party registered, time moves only to end a timed wait (a lone thread opening a station)."""
    clock = EventClock()
    ticks: list[float] = []
    clock.call_every(0.5, lambda: ticks.append(clock.now_s()))
    done = clock.event()
    seen: list[float] = []

    def waits_for_the_end() -> None:
        done.wait()
        seen.append(clock.now_s())

    t = threading.Thread(target=waits_for_the_end, daemon=True)
    t.start()
    while not clock._waiters:  # the waiter must be in place before the sleep
        threading.Event().wait(0.001)
    assert clock.now_s() == 0.0 and ticks == []
    clock.sleep_s(1.2)  # a timed wait: time moves to its end, running the timers due on the way
    assert clock.now_s() == 1.2 and ticks == [0.5, 1.0]
    done.set()
    t.join()
    assert seen == [1.2]


def test_a_ceiling_paces_station_time_against_the_wall() -> None:
    """At most `ceiling` station seconds per wall second: 2 station s at 100x take >= 20 ms of wall time
    (a busy host may make it longer, never shorter)."""
    import time

    clock = EventClock(ceiling=100.0)
    t0 = time.perf_counter()
    clock.sleep_s(2.0)
    assert time.perf_counter() - t0 >= 0.02 * 0.99
    assert clock.now_s() == 2.0


def test_a_pacemaker_keeps_a_paced_clock_flowing_while_nobody_acts() -> None:
    """A live station (paced, with a Pacemaker): time flows at most `ceiling` station s per wall s whoever waits,
    and no faster; timers on the way run. 0.3 s of wall time at 100x: at most 30 station s (plus one pacemaker
    step, 1 s), and on an idle machine about 30; at least 3 s here even on a host loaded 10-fold."""
    import time

    clock = EventClock(ceiling=100.0)
    ticks: list[float] = []
    clock.call_every(1.0, lambda: ticks.append(clock.now_s()))
    pacemaker = Pacemaker(clock)
    t0 = time.perf_counter()
    time.sleep(0.3)  # nobody waits on the clock: a person at the panel
    moved_s, wall_s = clock.now_s(), time.perf_counter() - t0
    pacemaker.stop()
    assert 3.0 <= moved_s <= 100.0 * wall_s + 100.0 * PACE_STEP_WALL_S
    assert ticks == [float(k) for k in range(1, len(ticks) + 1)] and len(ticks) >= 3
    stopped_s = clock.now_s()
    time.sleep(0.05)
    assert clock.now_s() == stopped_s  # stopped: time stands still again
    with pytest.raises(ValueError, match="paced clock"):
        Pacemaker(EventClock())


def test_the_end_of_a_lone_threads_wait_lets_time_move_on() -> None:
    """A lone thread's wait that ends (its event set) may be all that kept a waiting party from moving time:
    when it leaves, time moves on for the party (before, the party waited for ever)."""
    clock = EventClock()
    ready = clock.event()
    lone_done = threading.Event()

    def lone() -> None:
        ready.wait()  # no deadline: with no party, time stands still for it
        lone_done.set()

    t = threading.Thread(target=lone, daemon=True)
    t.start()
    while not clock._waiters:
        threading.Event().wait(0.001)
    woke: list[float] = []

    def party() -> None:
        ready.set()  # wakes the lone thread; its wait ends before or after this party sleeps
        clock.sleep_s(0.5)
        woke.append(clock.now_s())

    spawn_party(clock, "sleeper", party).join(timeout=10.0)
    t.join(timeout=10.0)
    assert lone_done.is_set() and woke == [0.5]


def _scenario() -> list[tuple[str, float]]:
    """Three parties and a periodic timer exchanging work in station time; the record of who saw what when."""
    clock = EventClock()
    log: list[tuple[str, float]] = []
    lock = threading.Lock()
    cond = clock.condition()
    queue: list[int] = []

    def note(who: str) -> None:
        with lock:
            log.append((who, clock.now_s()))

    def producer() -> None:
        for i in range(20):
            clock.sleep_s(0.013 * (i % 3 + 1))
            with cond:
                queue.append(i)
                cond.notify_all()
            note("put")

    def consumer() -> None:
        for _ in range(20):
            with cond:
                cond.wait_for(lambda: queue, timeout_s=10.0)
                queue.pop(0)
            note("got")
            sum(range(20_000))  # work that takes wall time, not station time

    clock.call_every(0.05, lambda: note("tick"))
    with clock.party("main"):
        threads = [spawn_party(clock, "producer", producer), spawn_party(clock, "consumer", consumer)]
        clock.sleep_s(1.0)
    for t in threads:
        t.join()
    return log


def test_the_same_exchange_gives_the_same_record_beside_two_busy_loops() -> None:
    quiet = _scenario()
    with busy_loops(2):
        loaded = _scenario()
    # Each party's record is the same to the bit; two parties running at one instant may append in either order.
    assert sorted(loaded) == sorted(quiet)
    assert [x for x in loaded if x[0] == "got"] == [x for x in quiet if x[0] == "got"]
    assert len([w for w, _ in quiet if w == "got"]) == 20
