"""Second instrument's counter channel: the counter/timer board's frames (drivers.counter_timer.driver's docstring)
on a port of its own, through the second instrument's kind (how it opens, how it is emulated).

Frame: sync A5 5A, type, u16 length LE, payload, CRC-16/CCITT-FALSE LE, worked out outside the code under test.
"""

from __future__ import annotations

from wire import FrozenClock, answers, scripted_port

from drivers.config import SerialSection
from drivers.second_instrument import kind
from drivers.world import SimStation

H = bytes.fromhex
STATUS_Q = H("a5 5a 22 00 00 3a 24")
STATUS_ARMED = H("a5 5a a2 0a 00 01 e8 03 00 00 78 56 34 12 00 65 df")  # armed, P 1000, ticks 0x12345678
STATUS_IDLE_1S = H("a5 5a a2 0a 00 00 00 00 00 00 00 2d 31 01 00 2c e8")  # idle, P 0, ticks at 1.0 s
ARM_3, ACK_ARM_OK = H("a5 5a 20 05 00 03 00 00 00 00 23 dd"), H("a5 5a a0 02 00 20 00 e6 d0")


def test_the_second_counter_speaks_the_counter_protocol() -> None:
    with scripted_port([(STATUS_Q, STATUS_ARMED), (ARM_3, ACK_ARM_OK)]) as port:
        counter = kind.open_counter(SerialSection(port=port, baud=921_600), FrozenClock(1.0))
        try:
            assert counter.status() == {"state": "armed", "preset": 1000, "ticks": 0x12345678, "fault": None}
            counter.arm(3)
        finally:
            counter.close()


def test_the_second_counters_emulator_answers_in_frames() -> None:
    emulator = kind.emulate(SerialSection(port=None, baud=921_600), SimStation(clock=FrozenClock(1.0)))
    try:
        assert emulator.name == "second-counter-emulator"
        assert answers(emulator, STATUS_Q) == STATUS_IDLE_1S
        assert answers(emulator, ARM_3) == ACK_ARM_OK
    finally:
        emulator.close()
