"""Serial fixtures: a simulated world, each emulator behind a real pty, and its driver.

Nothing is mocked: the driver opens the emulator's tty path with pyserial as
it would /dev/ttyUSB0. Each rig closes driver and emulator on teardown.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from devices.counter_timer.driver import CounterTimer
from devices.counter_timer.emulator import CounterEmulator
from devices.grating.driver import GratingReadHead
from devices.grating.emulator import GratingEmulator
from devices.indexing_head.driver import IndexingHead
from devices.indexing_head.emulator import IndexingEmulator
from devices.reference_marks.driver import ReferenceMarks
from devices.reference_marks.emulator import ReferenceEmulator
from devices.world import SimStation
from station.clock import VirtualClock

CRANK_ACCEL_RADPS2 = 1e6  # effectively a step to the commanded speed


def make_world(speed: float = 1.0, vibrate_hz: float = 10.0, start_s: float = 0.0) -> SimStation:
    """A simulated station on a VirtualClock; the table vibrating at vibrate_hz (0: at rest)."""
    world = SimStation(clock=VirtualClock(speed, start_s=start_s))
    if vibrate_hz > 0:
        world.crank.command_speed(2 * math.pi * vibrate_hz, CRANK_ACCEL_RADPS2, world.clock.now_s())
    return world


@pytest.fixture
def grating_rig_at() -> Iterator[Callable[..., tuple[Any, GratingEmulator, GratingReadHead]]]:
    """Factory: grating rig on a world whose clock runs `speed` times real time."""
    opened: list[tuple[GratingEmulator, GratingReadHead]] = []

    def make(speed: float = 1.0, vibrate_hz: float = 10.0) -> tuple[Any, GratingEmulator, GratingReadHead]:
        world = make_world(speed=speed, vibrate_hz=vibrate_hz)
        emu = GratingEmulator(world)
        emu.start()
        head = GratingReadHead(emu.port, timeout_s=0.3, clock=world.clock)
        opened.append((emu, head))
        head.open()
        return world, emu, head

    yield make
    for emu, head in opened:
        head.close()
        emu.close()


@pytest.fixture
def grating_rig(grating_rig_at) -> tuple[Any, GratingEmulator, GratingReadHead]:
    return grating_rig_at(speed=1.0, vibrate_hz=10.0)


@pytest.fixture
def reference_rig() -> Iterator[tuple[Any, ReferenceEmulator, ReferenceMarks]]:
    world = make_world(speed=1.0, vibrate_hz=10.0)
    with ReferenceEmulator(world) as emu:
        ref = ReferenceMarks(emu.port, timeout_s=0.3, silence_s=1.5, clock=world.clock).open()
        try:
            yield world, emu, ref
        finally:
            ref.close()


@pytest.fixture
def counter_rig() -> Iterator[Callable[..., tuple[Any, CounterEmulator, CounterTimer]]]:
    opened: list[tuple[CounterEmulator, CounterTimer]] = []

    def make(
        speed: float = 1.0, vibrate_hz: float = 10.0, start_s: float = 0.0
    ) -> tuple[Any, CounterEmulator, CounterTimer]:
        world = make_world(speed=speed, vibrate_hz=vibrate_hz, start_s=start_s)
        emu = CounterEmulator(world)
        emu.start()
        board = CounterTimer(emu.port, timeout_s=0.3, silence_s=1.5, clock=world.clock)
        opened.append((emu, board))
        board.open()
        return world, emu, board

    yield make
    for emu, board in opened:
        board.close()
        emu.close()


@pytest.fixture
def index_rig() -> Iterator[tuple[Any, IndexingEmulator, IndexingHead]]:
    world = make_world(speed=20.0, vibrate_hz=0.0)
    with IndexingEmulator(world) as emu:
        head = IndexingHead(emu.port, timeout_s=0.3, settle_time_s=0.2, poll_s=0.05, clock=world.clock).open()
        try:
            yield world, emu, head
        finally:
            head.close()
