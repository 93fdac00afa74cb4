"""The python-can interface `station_sim`: CAN frames delivered in the sender's thread, on the station clock.

Registered through the `can.interface` entry point (pyproject.toml), so drivers
and emulators open it as they open `socketcan` on a real station:
`can.Bus(interface="station_sim", channel=...)`. Like python-can's `virtual`
interface, every frame reaches every other bus on the channel, not the sender.
Unlike it, nothing crosses a thread: `send()` appends the frame for each
receiving bus to the channel's FIFO, and the outermost `send()` of the channel
drains it in order, delivering to the listeners of the receiving bus's
`can.Notifier` (canopen's `Network.connect()` makes one) or, for a bus without
one, to its `recv()` queue. A listener that sends from its callback only queues
(no recursion); its frame is delivered by the same loop after the frames before
it. A reply is therefore in its receiver's hands before the `send()` that caused
it returns, and a frame costs microseconds instead of a thread hand-off.

`bind_clock(channel, clock)` gives a channel its clock: frames are stamped with
its `now_s()` and `send_periodic` (heartbeats, cyclic frames) runs on its
`call_every`. An unbound channel runs on the host's wall clock.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import can
from can.broadcastmanager import (
    LimitedDurationCyclicSendTaskABC,
    ModifiableCyclicTaskABC,
    RestartableCyclicTaskABC,
)

from station.clock import Clock, TimerHandle, host_clock

log = logging.getLogger(__name__)

INTERFACE = "station_sim"  # its name in the `can.interface` entry points (pyproject.toml)
IDLE_POLL_S = 0.05  # how soon a stopped Notifier's idle reader notices, so that Network.disconnect() is prompt


class _Channel:
    """The buses on one channel name, its clock and the FIFO of frames still to deliver."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.bound: Clock | None = None
        self.buses: list[StationSimBus] = []
        self.fifo: deque[tuple[StationSimBus, can.Message]] = deque()
        self.draining = False
        self.lock = threading.Lock()

    @property
    def clock(self) -> Clock:
        return self.bound if self.bound is not None else host_clock()


_channels: dict[str, _Channel] = {}
_channels_lock = threading.Lock()


def _open_channel(name: str) -> _Channel:
    with _channels_lock:
        ch = _channels.get(name)
        if ch is None:
            ch = _channels[name] = _Channel(name)
        return ch


def _release_channel(ch: _Channel) -> None:
    """Forget a channel that has no bus and no clock of its own (channel names are often unique per test)."""
    with _channels_lock, ch.lock:
        if not ch.buses and ch.bound is None and _channels.get(ch.name) is ch:
            del _channels[ch.name]


def bind_clock(channel: str, clock: Clock | None) -> None:
    """Buses on `channel` stamp frames and send periodic ones on `clock` (None: back to the host's wall clock).

    Bind before opening the buses: a bus without a notifier waits in `recv()` on the clock's link as bound
    when it opened."""
    ch = _open_channel(channel)
    with ch.lock:
        ch.bound = clock
    _release_channel(ch)


def _received(msg: can.Message, timestamp_s: float, channel: str) -> can.Message:
    """A receiver's own copy of the frame (its own data: a sender may change its message after send()),
    stamped with the station time it crossed the bus."""
    return can.Message(
        timestamp=timestamp_s,
        arbitration_id=msg.arbitration_id,
        is_extended_id=msg.is_extended_id,
        is_remote_frame=msg.is_remote_frame,
        is_error_frame=msg.is_error_frame,
        channel=channel,
        dlc=msg.dlc,
        data=bytearray(msg.data),
        is_fd=msg.is_fd,
        is_rx=True,
        bitrate_switch=msg.bitrate_switch,
        error_state_indicator=msg.error_state_indicator,
    )


class StationSimBus(can.BusABC):
    """One node's connection to a `station_sim` channel."""

    def __init__(self, channel: Any = "station", can_filters: Any = None, **kwargs: Any) -> None:
        self._channel = _open_channel(str(channel))
        self.channel_info = f"station_sim channel {channel}"
        self._rx: deque[can.Message] = deque()
        self._notifier: can.Notifier | None = None
        self._rx_cond = self._channel.clock.link.condition()
        # a Notifier's reader never gets a frame here (send() hands them to its listeners): it idles in wall time
        self._closed = host_clock().event()
        with self._channel.lock:
            self._channel.buses.append(self)
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    @property
    def clock(self) -> Clock:
        return self._channel.clock

    # ---- sending

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        ch = self._channel
        with ch.lock:
            self._check_open()
            t_s = ch.clock.now_s()
            for bus in ch.buses:
                if bus is not self:
                    ch.fifo.append((bus, _received(msg, t_s, ch.name)))
            if ch.draining:
                return  # the outermost send() of the channel delivers it
            ch.draining = True
        try:
            while True:
                with ch.lock:
                    if not ch.fifo:
                        ch.draining = False
                        return
                    bus, frame = ch.fifo.popleft()
                bus._deliver(frame)
        except BaseException:
            with ch.lock:
                ch.draining = False
            raise

    def _active_notifier(self) -> can.Notifier | None:
        """The bus's running Notifier: python-can lets a bus have one at a time, so it is kept while it runs
        (looking it up in the registry was a tenth of a frame's cost)."""
        notifier = self._notifier
        if notifier is None or notifier.stopped:
            notifier = self._notifier = next((n for n in can.Notifier.find_instances(self) if not n.stopped), None)
        return notifier

    def _deliver(self, frame: can.Message) -> None:
        if self._is_shutdown or not self._matches_filters(frame):
            return
        notifier = self._active_notifier()
        if notifier is None:
            with self._rx_cond:
                self._rx.append(frame)
                self._rx_cond.notify_all()
            return
        for listener in list(notifier.listeners):
            try:
                listener(frame)
            except Exception as exc:  # one receiver's failure must not reach the sender or other receivers
                notifier.exception = exc
                on_error = getattr(listener, "on_error", None)
                if on_error is None:
                    log.exception("%s: listener %r failed", self.channel_info, listener)
                else:
                    on_error(exc)

    # ---- receiving

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame of a bus without a notifier; a notifier's reader idles here until its notifier stops.

        Raises CanOperationError once the bus is shut down (a wait in progress ends with it), as `virtual` does."""
        self._check_open()
        notifiers = can.Notifier.find_instances(self)
        if notifiers and not self._rx:
            self._idle(notifiers, timeout)
            return None
        return super().recv(timeout)

    def _idle(self, notifiers: Sequence[can.Notifier], timeout_s: float | None) -> None:
        wall = host_clock()
        deadline_s = math.inf if timeout_s is None else wall.now_s() + timeout_s
        while not all(n.stopped for n in notifiers):
            left_s = deadline_s - wall.now_s()
            if left_s <= 0:
                return
            if self._closed.wait(timeout_s=min(left_s, IDLE_POLL_S)):
                self._check_open()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        with self._rx_cond:
            self._rx_cond.wait_for(lambda: self._rx or self._is_shutdown, timeout_s=timeout)
            if not self._rx:
                self._check_open()
                return None, True
            return self._rx.popleft(), True

    def _check_open(self) -> None:
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.channel_info}: the bus is shut down")

    # ---- periodic frames on the clock

    def _send_periodic_internal(
        self,
        msgs: Sequence[can.Message] | can.Message,
        period: float,
        duration: float | None = None,
        autostart: bool = True,
        modifier_callback: Callable[[can.Message], None] | None = None,
    ) -> _ClockCyclicTask:
        task = _ClockCyclicTask(self, msgs, period, duration, modifier_callback)
        if autostart:
            task.start()
        return task

    def shutdown(self) -> None:
        """Leave the channel: periodic frames stop, nothing more is delivered, waits in recv() end. Idempotent."""
        if self._is_shutdown:
            return
        super().shutdown()  # marks the bus shut down and stops its periodic tasks
        ch = self._channel
        with ch.lock:
            if self in ch.buses:
                ch.buses.remove(self)
        with self._rx_cond:
            self._rx_cond.notify_all()
        self._closed.set()
        _release_channel(ch)


class _ClockCyclicTask(LimitedDurationCyclicSendTaskABC, ModifiableCyclicTaskABC, RestartableCyclicTaskABC):
    """send_periodic on the bus's clock: the first frame at once, then one `call_every` timer.

    With a duration, the frames due at start + k * period for k * period < duration are sent."""

    def __init__(
        self,
        bus: StationSimBus,
        msgs: Sequence[can.Message] | can.Message,
        period: float,
        duration: float | None,
        modifier_callback: Callable[[can.Message], None] | None,
    ) -> None:
        super().__init__(msgs, period, duration)
        self._bus = bus
        self._modifier = modifier_callback
        self._lock = threading.Lock()
        self._timer: TimerHandle | None = None
        self._index = 0
        self._frames_left = math.inf

    def start(self) -> None:
        with self._lock:
            if self._timer is not None:
                return
            if self.duration is not None:
                self._frames_left = math.ceil(round(self.duration / self.period, 9))
            self._index = 0
            self._timer = self._bus.clock.call_every(self.period, self._send_next)
        self._send_next()

    def stop(self) -> None:
        with self._lock:
            timer, self._timer = self._timer, None
        if timer is not None:
            timer.cancel()

    def _send_next(self) -> None:
        with self._lock:
            if self._timer is None:
                return
            done = self._frames_left <= 0
            if not done:
                self._frames_left -= 1
                msg = self.messages[self._index]
                self._index = (self._index + 1) % len(self.messages)
        if done:
            self.stop()  # the bus's wrapper of stop() also forgets the task
            return
        if self._modifier is not None:
            self._modifier(msg)
        try:
            self._bus.send(msg)
        except can.CanOperationError:
            self.stop()  # the bus was shut down
