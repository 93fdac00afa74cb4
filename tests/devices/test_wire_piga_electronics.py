"""PIGA electronics: known-answer lines from the SCPI-like protocol in drivers.piga_electronics.driver's docstring.

Command `<body>*<cs>` LF, reply `<body>*<cs>` CR LF; cs the XOR of the body's bytes as two upper-case hex
digits (worked out by hand for each line below). Every command gets exactly one reply; rejections are
`ERR <code>,"<text>"` (-100 unknown command, -104 data type, -222 out of range, -310 bad checksum,
301 servo fault latched).
"""

from __future__ import annotations

import contextlib

import pytest
from wire import FrozenClock, answers, driver_on

from drivers.errors import ChecksumError, DeviceFault, LimitError
from drivers.piga_electronics.driver import PigaElectronics, ServoStatus
from drivers.piga_electronics.emulator import PigaElectronicsEmulator
from drivers.world import SimStation

IDN_Q, OFFS_Q, STAT_Q, ERR_Q = b"*IDN?*56\n", b"SERV:OFFS?*0B\n", b"SERV:STAT?*05\n", b"SYST:ERR?*4D\n"
SET_MINUS_0_85 = b"SERV:OFFS -0.850*1A\n"
OK = b"OK*04\r\n"
IDENTITY = b"BIACD,PIGA-PCB,SIM-0001,2.1*54\r\n"
LOCKED = b"LOCK,0.000*09\r\n"
OUT_OF_RANGE = b'ERR -222,"data out of range"*7E\r\n'


def _board_on(transcript: list[tuple[bytes, bytes]], **kw: float) -> contextlib.AbstractContextManager[PigaElectronics]:
    """The driver on a port that plays `transcript`."""
    return driver_on(transcript, lambda port: PigaElectronics(port, timeout_s=0.3, clock=FrozenClock(), **kw))


def test_identity() -> None:
    with _board_on([(IDN_Q, IDENTITY)]) as board:
        assert board.identify() == "BIACD,PIGA-PCB,SIM-0001,2.1"


def test_set_the_offset_and_read_it_back() -> None:
    with _board_on([(SET_MINUS_0_85, OK), (OFFS_Q, b"-0.850*0E\r\n")]) as board:
        assert board.set_offset_arcsec(-0.85) == -0.85


def test_a_readback_that_disagrees_is_a_device_fault() -> None:
    transcript = [(SET_MINUS_0_85, OK), (OFFS_Q, b"-0.851*0F\r\n")]
    with _board_on(transcript) as board, pytest.raises(DeviceFault, match="read back"):
        board.set_offset_arcsec(-0.85)


def test_an_offset_beyond_the_limit_sends_nothing() -> None:
    with _board_on([], offset_max_arcsec=10.0) as board, pytest.raises(LimitError):
        board.set_offset_arcsec(40.0)


def test_a_rejection_is_a_device_fault() -> None:
    transcript = [(b"SERV:OFFS 40.000*0E\n", OUT_OF_RANGE)]
    with _board_on(transcript, offset_max_arcsec=50.0) as board, pytest.raises(DeviceFault) as info:
        board.set_offset_arcsec(40.0)
    assert (info.value.field, info.value.value) == ("reply", '-222,"data out of range"')


def test_wait_until_locked() -> None:
    with _board_on([(STAT_Q, b"SETTLE,0.850*10\r\n"), (STAT_Q, LOCKED)], poll_s=0.2) as board:
        assert board.wait_locked(timeout_s=5.0) == ServoStatus("LOCK", 0.0)


def test_a_servo_fault_is_a_device_fault() -> None:
    with _board_on([(STAT_Q, b"FAULT,99.999*71\r\n")]) as board, pytest.raises(DeviceFault) as info:
        board.wait_locked(timeout_s=5.0)
    assert info.value.field == "servo"


def test_a_bad_checksum_is_a_checksum_error_and_the_query_asked_again() -> None:
    with _board_on([(STAT_Q, b"LOCK,0.000*08\r\n"), (STAT_Q, LOCKED)]) as board:
        assert board.servo_status() == ServoStatus("LOCK", 0.0)
    with _board_on([(STAT_Q, b"LOCK,0.000*08\r\n")], retries=0) as board, pytest.raises(ChecksumError):
        board.servo_status()


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> PigaElectronicsEmulator:
    return PigaElectronicsEmulator(SimStation(clock=FrozenClock()), settle_s=2.0, offset_range_arcsec=30.0)


def test_emulator_offset_and_settling(emulator: PigaElectronicsEmulator) -> None:
    """After a step of 0.85" the servo settles as 0.85 exp(-5 t / settle_s): 0.313" at 0.4 s, locked at 2 s."""
    assert answers(emulator, IDN_Q) == IDENTITY
    assert answers(emulator, OFFS_Q) == b"0.000*2E\r\n"
    assert answers(emulator, SET_MINUS_0_85) == OK
    assert answers(emulator, OFFS_Q) == b"-0.850*0E\r\n"
    assert answers(emulator, STAT_Q) == b"SETTLE,0.850*10\r\n"
    emulator.clock.advance_s(0.4)
    assert answers(emulator, STAT_Q) == b"SETTLE,0.313*1C\r\n"
    emulator.clock.advance_s(1.6)
    assert answers(emulator, STAT_Q) == LOCKED


def test_emulator_rejections_and_the_error_queue(emulator: PigaElectronicsEmulator) -> None:
    assert answers(emulator, b"SERV:OFFS 40.000*0E\n") == OUT_OF_RANGE
    assert answers(emulator, b"SERV:OFFS abc*74\n") == b'ERR -104,"data type"*79\r\n'
    assert answers(emulator, b"FOO*46\n") == b'ERR -100,"unknown command"*7A\r\n'
    assert answers(emulator, b"SERV:OFFS -0.850*1B\n") == b'ERR -310,"checksum"*5B\r\n'
    assert answers(emulator, ERR_Q) == b'-222,"data out of range"*1B\r\n'
    assert answers(emulator, b"*CLS*76\n") == OK
    assert answers(emulator, ERR_Q) == b'0,"No error"*65\r\n'


def test_emulator_servo_fault_latches_until_cls(emulator: PigaElectronicsEmulator) -> None:
    emulator.lose_lock()
    assert answers(emulator, STAT_Q) == b"FAULT,99.999*71\r\n"
    assert answers(emulator, SET_MINUS_0_85) == b'ERR 301,"servo fault"*4C\r\n'
    assert answers(emulator, b"*CLS*76\n") == OK
    emulator.clock.advance_s(2.0)
    assert answers(emulator, STAT_Q) == LOCKED
