"""The `station_sim` python-can interface (drivers/sim_can.py): delivery in the sender's thread, in order, without
recursion; canopen on it unchanged; send_periodic on the channel's clock; a clean shutdown.

Timing is asserted in station seconds on a VirtualClock running at 1e-6 of wall speed, moved on by `advance_s`:
its time drifts from the advances by 1e-6 s per wall second, so <= 3e-4 s over the 300 s test timeout (DRIFT_S).
Wall-time waits below only bound how long a test may hang; none is asserted.
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import pytest

from drivers.sim_can import StationSimBus, bind_clock
from station.clock import VirtualClock

EDS = Path(__file__).parents[2] / "config" / "eds" / "vibration_table_servo.eds"
NODE_ID = 5
PERIOD_S = 0.1
DRIFT_S = 1e-3  # > 3e-4 s (module docstring)
HANG_S = 10.0  # wall seconds a test may wait for the clock's timer thread before it fails


@pytest.fixture
def channel() -> Iterator[str]:
    name = f"sim-can-{uuid.uuid4().hex[:8]}"
    yield name
    bind_clock(name, None)


@pytest.fixture
def clock(channel: str) -> VirtualClock:
    """A clock that moves only when the test advances it (to DRIFT_S), bound to the channel."""
    clock = VirtualClock(speed=1e-6)
    bind_clock(channel, clock)
    return clock


def bus(channel: str) -> StationSimBus:
    opened = can.Bus(interface="station_sim", channel=channel)
    assert isinstance(opened, StationSimBus)
    return opened


def frame(can_id: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


def drain(rx: can.BusABC) -> list[can.Message]:
    return list(iter(lambda: rx.recv(timeout=0), None))


def advance(clock: VirtualClock, duration_s: float) -> None:
    """Move the clock on and wait until its timers due by then have run (they run in due order, so a marker
    timer due now runs after them)."""
    clock.advance_s(duration_s)
    ran = threading.Event()
    clock.call_at(clock.now_s(), ran.set)
    assert ran.wait(HANG_S), "the clock's timer thread did not run"


def test_the_entry_point_opens_it() -> None:
    with can.Bus(interface="station_sim", channel="x") as opened:
        assert isinstance(opened, StationSimBus)


def test_frames_arrive_in_order_in_the_senders_thread_and_an_answer_does_not_recurse(channel: str) -> None:
    a, b, c = bus(channel), bus(channel), bus(channel)
    seen_by_c: list[int] = []
    threads: set[int] = set()
    depth = 0
    max_depth = 0

    def answer(msg: can.Message) -> None:
        nonlocal depth, max_depth
        depth += 1
        max_depth = max(max_depth, depth)
        threads.add(threading.get_ident())
        if msg.arbitration_id == 0x1:
            b.send(frame(0x10))
            assert 0x10 not in seen_by_c  # only queued: delivered after the frames before it
        depth -= 1

    def record(msg: can.Message) -> None:
        threads.add(threading.get_ident())
        seen_by_c.append(msg.arbitration_id)

    with can.Notifier(b, [answer]), can.Notifier(c, [record]):
        a.send(frame(0x1))
        assert seen_by_c == [0x1, 0x10]  # the answer is in before the send that caused it returns
        a.send(frame(0x2))
        assert seen_by_c == [0x1, 0x10, 0x2]
        assert [m.arbitration_id for m in drain(a)] == [0x10]  # no notifier on a: its recv() queue
    assert threads == {threading.get_ident()}
    assert max_depth == 1
    for each in (a, b, c):
        each.shutdown()


def test_a_long_exchange_of_answers_stays_flat(channel: str) -> None:
    """Each side answers the other 5000 times: recursion would pass Python's limit (1000 frames)."""
    ping, pong = bus(channel), bus(channel)
    counts = {"ping": 0, "pong": 0}

    def answer_from(side: can.BusABC, name: str) -> can.Listener:
        class Answer(can.Listener):
            def on_message_received(self, msg: can.Message) -> None:
                counts[name] += 1
                if msg.data[0] < 250 or counts[name] < 5000:
                    side.send(frame(0x100, bytes([(msg.data[0] + 1) % 256])))

        return Answer()

    with can.Notifier(ping, [answer_from(ping, "ping")]), can.Notifier(pong, [answer_from(pong, "pong")]):
        ping.send(frame(0x100, b"\x00"))
    assert counts["ping"] >= 5000 and counts["pong"] >= 5000
    ping.shutdown()
    pong.shutdown()


def test_a_failing_listener_reaches_neither_the_sender_nor_the_others(channel: str) -> None:
    a, b = bus(channel), bus(channel)
    got: list[int] = []

    def fail(msg: can.Message) -> None:
        raise RuntimeError("listener bug")

    with can.Notifier(b, [fail, lambda msg: got.append(msg.arbitration_id)]) as notifier:
        a.send(frame(0x7))
        assert got == [0x7]
        assert isinstance(notifier.exception, RuntimeError)
    a.shutdown()
    b.shutdown()


def test_filters_and_time_stamps_of_the_bound_clock(channel: str) -> None:
    clock = VirtualClock(speed=1e-6, start_s=100.0)
    bind_clock(channel, clock)
    a, b = bus(channel), bus(channel)
    b.set_filters([{"can_id": 0x180, "can_mask": 0x780, "extended": False}])
    a.send(frame(0x185, b"\x01\x02"))
    a.send(frame(0x605))
    clock.advance_s(2.5)
    a.send(frame(0x186))
    got = drain(b)
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(0x185, b"\x01\x02"), (0x186, b"")]
    assert got[0].timestamp == pytest.approx(100.0, abs=DRIFT_S)
    assert got[1].timestamp == pytest.approx(102.5, abs=DRIFT_S)
    assert all(m.channel == channel and m.is_rx for m in got)
    a.shutdown()
    b.shutdown()


def test_canopen_sdo_between_a_local_and_a_remote_node(channel: str) -> None:
    """The answer is in the client's queue before the request's send() returns: a zero response timeout suffices."""
    drive = canopen.Network()
    drive.connect(interface="station_sim", channel=channel)
    master = canopen.Network()
    master.connect(interface="station_sim", channel=channel)
    try:
        local = drive.create_node(NODE_ID, str(EDS))
        served: set[int] = set()
        local.add_read_callback(lambda **kw: served.add(threading.get_ident()))
        remote = master.add_node(NODE_ID, str(EDS))
        remote.sdo.RESPONSE_TIMEOUT = 0.0
        assert remote.sdo[0x1017].raw == 100  # the EDS default
        remote.sdo[0x1017].raw = 250
        assert remote.sdo[0x1017].raw == 250
        assert local.sdo[0x1017].raw == 250
        assert served == {threading.get_ident()}
    finally:
        master.disconnect()
        drive.disconnect()


def test_send_periodic_runs_on_the_channels_clock(channel: str, clock: VirtualClock) -> None:
    tx, rx = bus(channel), bus(channel)
    t0_s = clock.now_s()
    task = tx.send_periodic(frame(0x705, b"\x7f"), PERIOD_S)
    assert len(drain(rx)) == 1  # the first at once, as python-can's own task
    advance(clock, PERIOD_S / 2)
    assert drain(rx) == []
    stamps_s = [t0_s]
    for _ in range(5):
        advance(clock, PERIOD_S)
        stamps_s += [m.timestamp for m in drain(rx)]
    assert stamps_s == pytest.approx([t0_s + k * PERIOD_S + (PERIOD_S / 2 if k else 0) for k in range(6)], abs=DRIFT_S)
    task.stop()
    advance(clock, 3 * PERIOD_S)
    assert drain(rx) == []
    tx.shutdown()
    rx.shutdown()


def test_send_periodic_duration(channel: str, clock: VirtualClock) -> None:
    """Frames at k * period for k * period < duration: 0, 0.1, 0.2, 0.3 s of a 0.35 s duration."""
    tx, rx = bus(channel), bus(channel)
    t0_s = clock.now_s()
    tx.send_periodic(frame(0x181), PERIOD_S, duration=0.35)
    for _ in range(6):
        advance(clock, PERIOD_S)
    stamps_s = [m.timestamp - t0_s for m in drain(rx)]
    assert stamps_s == pytest.approx([0.0, 0.1, 0.2, 0.3], abs=DRIFT_S)
    assert tx._periodic_tasks == []  # an ended task is forgotten, like a stopped one
    tx.shutdown()
    rx.shutdown()


def test_modify_data_and_modifier_callback(channel: str, clock: VirtualClock) -> None:
    tx, rx = bus(channel), bus(channel)
    task = tx.send_periodic(frame(0x701, b"\x7f"), PERIOD_S)
    advance(clock, PERIOD_S)
    assert isinstance(task, can.ModifiableCyclicTaskABC)
    task.modify_data(frame(0x701, b"\x05"))
    advance(clock, PERIOD_S)
    task.stop()

    def count(msg: can.Message) -> None:
        msg.data[0] += 1

    tx.send_periodic(frame(0x702, b"\x00"), PERIOD_S, modifier_callback=count)
    advance(clock, PERIOD_S)
    advance(clock, PERIOD_S)
    assert [(m.arbitration_id, bytes(m.data)) for m in drain(rx)] == [
        (0x701, b"\x7f"),
        (0x701, b"\x7f"),
        (0x701, b"\x05"),
        (0x702, b"\x01"),
        (0x702, b"\x02"),
        (0x702, b"\x03"),
    ]
    tx.shutdown()
    rx.shutdown()


def test_a_canopen_heartbeat_follows_the_nmt_state(channel: str, clock: VirtualClock) -> None:
    """canopen's PeriodicMessageTask.update() changes the heartbeat's data through modify_data."""
    drive = canopen.Network()
    drive.connect(interface="station_sim", channel=channel)
    rx = bus(channel)
    try:
        local = drive.create_node(NODE_ID, str(EDS))
        local.nmt.state = "PRE-OPERATIONAL"  # starts the 0x1017 heartbeat (100 ms)
        advance(clock, 0.1)
        local.nmt.state = "OPERATIONAL"
        advance(clock, 0.1)
        beats = [bytes(m.data) for m in drain(rx) if m.arbitration_id == 0x700 + NODE_ID]
        assert beats == [b"\x7f", b"\x7f", b"\x05"]
    finally:
        drive.disconnect()
        rx.shutdown()


def test_shutdown_is_clean_and_idempotent(channel: str, clock: VirtualClock) -> None:
    a, b = bus(channel), bus(channel)
    a.send_periodic(frame(0x700), PERIOD_S)
    ended: list[Exception] = []

    def read() -> None:
        try:
            a.recv()
        except can.CanOperationError as e:
            ended.append(e)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    a.shutdown()
    a.shutdown()
    reader.join(HANG_S)
    assert not reader.is_alive() and len(ended) == 1  # a recv() without timeout ends with the bus, as virtual's
    with pytest.raises(can.CanOperationError):
        a.send(frame(0x1))
    with pytest.raises(can.CanOperationError):
        a.recv(timeout=0)
    drain(b)
    b.send(frame(0x2))  # reaches nobody: a has left the channel
    advance(clock, 3 * PERIOD_S)
    assert drain(b) == []  # the periodic task stopped with its bus
    b.shutdown()


def test_network_disconnect_does_not_wait_for_the_notifier_cycle(channel: str) -> None:
    """The idle reader of a Notifier returns once the notifier stops, well within its own cycle: with a cycle
    longer than the stop's join timeout, a reader still in its recv() would be alive after disconnect()."""
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 60.0
    network.NOTIFIER_SHUTDOWN_TIMEOUT = HANG_S
    network.connect(interface="station_sim", channel=channel)
    notifier = network.notifier
    assert notifier is not None
    network.disconnect()
    assert not any(isinstance(r, threading.Thread) and r.is_alive() for r in notifier._readers)
