"""Serial fixtures: a simulated world, each emulator behind a real pty or a sim:// line, and its driver.

Nothing is mocked: the driver opens the emulator's tty path or sim:// URL with
pyserial as it would /dev/ttyUSB0. Every device rig runs each of its tests on
both transports (`transport`); a test about the wall-time pacing of the pty
overrides it with `@pytest.mark.parametrize("transport", ["pty"])` and says why.
Each rig closes driver and emulator on teardown.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from links import serve

from drivers.counter_timer.driver import CounterTimer
from drivers.counter_timer.emulator import CounterEmulator
from drivers.grating.driver import GratingReadHead
from drivers.grating.emulator import GratingEmulator
from drivers.indexing_head.driver import IndexingHead
from drivers.indexing_head.emulator import IndexingEmulator
from drivers.reference_marks.driver import ReferenceMarks
from drivers.reference_marks.emulator import ReferenceEmulator
from drivers.world import SimStation
from station.clock import VirtualClock

CRANK_ACCEL_RADPS2 = 1e6  # effectively a step to the commanded speed


def make_world(speed: float = 1.0, vibrate_hz: float = 10.0, start_s: float = 0.0) -> SimStation:
    """A simulated station on a VirtualClock; the table vibrating at vibrate_hz (0: at rest)."""
    world = SimStation(clock=VirtualClock(speed, start_s=start_s))
    if vibrate_hz > 0:
        world.crank.command_speed(2 * math.pi * vibrate_hz, CRANK_ACCEL_RADPS2, world.clock.now_s())
    return world


@pytest.fixture
def grating_rig_at(transport: str) -> Iterator[Callable[..., tuple[Any, GratingEmulator, GratingReadHead]]]:
    """Factory: grating rig on a world whose clock runs `speed` times real time."""
    opened: list[tuple[GratingEmulator, GratingReadHead]] = []

    def make(speed: float = 1.0, vibrate_hz: float = 10.0) -> tuple[Any, GratingEmulator, GratingReadHead]:
        world = make_world(speed=speed, vibrate_hz=vibrate_hz)
        emu = GratingEmulator(world)
        head = GratingReadHead(serve(emu, transport), timeout_s=0.3, clock=world.clock)
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
def reference_rig(transport: str) -> Iterator[tuple[Any, ReferenceEmulator, ReferenceMarks]]:
    world = make_world(speed=1.0, vibrate_hz=10.0)
    emu = ReferenceEmulator(world)
    try:
        ref = ReferenceMarks(serve(emu, transport), timeout_s=0.3, silence_s=1.5, clock=world.clock).open()
        try:
            yield world, emu, ref
        finally:
            ref.close()
    finally:
        emu.close()


@pytest.fixture
def counter_rig(transport: str) -> Iterator[Callable[..., tuple[Any, CounterEmulator, CounterTimer]]]:
    opened: list[tuple[CounterEmulator, CounterTimer]] = []

    def make(
        speed: float = 1.0, vibrate_hz: float = 10.0, start_s: float = 0.0
    ) -> tuple[Any, CounterEmulator, CounterTimer]:
        world = make_world(speed=speed, vibrate_hz=vibrate_hz, start_s=start_s)
        emu = CounterEmulator(world)
        board = CounterTimer(serve(emu, transport), timeout_s=0.3, silence_s=1.5, clock=world.clock)
        opened.append((emu, board))
        board.open()
        return world, emu, board

    yield make
    for emu, board in opened:
        board.close()
        emu.close()


@pytest.fixture
def index_rig(transport: str) -> Iterator[tuple[Any, IndexingEmulator, IndexingHead]]:
    world = make_world(speed=20.0, vibrate_hz=0.0)
    emu = IndexingEmulator(world)
    try:
        port = serve(emu, transport)
        head = IndexingHead(port, timeout_s=0.3, settle_time_s=0.2, poll_s=0.05, clock=world.clock).open()
        try:
            yield world, emu, head
        finally:
            head.close()
    finally:
        emu.close()
