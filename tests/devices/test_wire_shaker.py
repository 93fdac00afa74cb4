"""Shaker controller: known-answer lines from the protocol in drivers.shaker.driver's docstring.

Command `<text>*<crc>` LF, reply `<OK|ER> <data>*<crc>` CR LF; crc the CRC-16/CCITT-FALSE (poly 0x1021, init
0xFFFF) of the text before `*`, four upper-case hex digits (worked out from that definition for each line
below, outside the code under test). STAT? answers `OK <state> <mode> <level_g> <alarm>`.
"""

from __future__ import annotations

import contextlib

import pytest
from wire import FrozenClock, answers, driver_on

from drivers.errors import ChecksumError, DeviceFault, FrameError, LimitError
from drivers.shaker.driver import ShakerController, ShakerStatus
from drivers.shaker.emulator import ShakerEmulator
from drivers.shaker.envelope import ShakerSection
from drivers.world import SimStation

# config/stations/shaker-sim.toml's table: 1-2500 Hz, 50 kN, 75 kg moving and 42 kg mounted
TABLE = ShakerSection(port=None, baud=115_200, freq_min_hz=1.0, freq_max_hz=2500.0, displacement_max_m=0.0255,
                      velocity_max_mps=2.0, accel_max_g=100.0, thrust_sine_n=50_000.0, thrust_random_n=50_000.0,
                      moving_mass_kg=75.0, payload_kg=42.0, payload_max_kg=500.0, ramp_max_s=30.0)  # fmt: skip
IDN_Q, STAT_Q = b"IDN?*3139\n", b"STAT?*7A7C\n"
SINE_100_2 = b"SINE 100.0000 2.0000*C276\n"
START_1 = b"START 1.000*DD0D\n"
OK_0 = b"OK 0*E35B\r\n"
RUNNING = b"OK RUN SINE 2.00000 --*C9EF\r\n"


STOP_2 = b"STOP 2.000*FD25\n"


def _controller_on(
    transcript: list[tuple[bytes, bytes]], retries: int = 2
) -> contextlib.AbstractContextManager[ShakerController]:
    """The driver on a port that plays `transcript`, then the STOP over 2 s that the driver sends as it closes."""
    return driver_on(
        [*transcript, (STOP_2, OK_0)], lambda p: ShakerController(p, TABLE, timeout_s=0.3, retries=retries)
    )


def test_identity() -> None:
    with _controller_on([(IDN_Q, b"OK THV710A-EMU 0002*D2C0\r\n")]) as shaker:
        assert shaker.identify() == "THV710A-EMU 0002"


def test_a_sine_test_set_started_and_stopped() -> None:
    transcript = [(SINE_100_2, OK_0), (START_1, OK_0), (STAT_Q, RUNNING), (STOP_2, OK_0)]
    with _controller_on(transcript) as shaker:
        shaker.set_sine(100.0, 2.0)
        shaker.start(1.0)
        assert shaker.status() == ShakerStatus("RUN", "SINE", 2.0, None)
        shaker.stop(2.0)


def test_a_random_test_and_an_abort() -> None:
    with _controller_on([(b"RAND 1.0000 20.0000 2000.0000*2A59\n", OK_0), (b"ABORT*6AF1\n", OK_0)]) as shaker:
        shaker.set_random(1.0, 20.0, 2000.0)
        shaker.abort()


def test_a_test_outside_the_envelope_sends_nothing() -> None:
    with _controller_on([]) as shaker, pytest.raises(LimitError) as info:
        shaker.set_sine(5000.0, 2.0)
    assert info.value.field == "freq_hz"


def test_a_latched_alarm_is_a_device_fault() -> None:
    with (
        _controller_on([(STAT_Q, b"OK ALARM SINE 0.00000 OVERTRAVEL*103E\r\n")]) as shaker,
        pytest.raises(DeviceFault) as info,
    ):
        shaker.check()
    assert (info.value.field, info.value.value) == ("alarm", "OVERTRAVEL")


def test_an_er_reply_is_a_device_fault() -> None:
    with (
        _controller_on([(SINE_100_2, b"ER BUSY the table runs*4A31\r\n")]) as shaker,
        pytest.raises(DeviceFault) as info,
    ):
        shaker.set_sine(100.0, 2.0)
    assert info.value.value == "BUSY the table runs"


def test_an_unknown_mode_is_a_frame_error() -> None:
    with (
        _controller_on([(STAT_Q, b"OK RUN MAYBE 2.00000 --*B97A\r\n")], retries=0) as shaker,
        pytest.raises(FrameError, match="unknown state or mode"),
    ):
        shaker.status()


def test_a_bad_crc_is_retried_on_a_query_but_not_on_start() -> None:
    damaged = RUNNING.replace(b"*C9EF", b"*C9EE")
    with _controller_on([(STAT_Q, damaged), (STAT_Q, RUNNING)]) as shaker:
        assert shaker.status().state == "RUN"
    with _controller_on([(START_1, OK_0.replace(b"E35B", b"E35C"))]) as shaker, pytest.raises(ChecksumError):
        shaker.start(1.0)


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> ShakerEmulator:
    return ShakerEmulator(SimStation(clock=FrozenClock()), TABLE)


def test_emulator_replies(emulator: ShakerEmulator) -> None:
    assert answers(emulator, IDN_Q) == b"OK THV710A-EMU 0002*D2C0\r\n"
    assert answers(emulator, STAT_Q) == b"OK IDLE NONE 0.00000 --*8958\r\n"
    assert answers(emulator, START_1) == b"ER SYNTAX no test set*71F7\r\n"
    assert answers(emulator, SINE_100_2) == OK_0
    assert answers(emulator, b"FOO*C748\n") == b"ER SYNTAX 'FOO'*9B5F\r\n"


def test_emulator_refuses_what_the_table_cannot_do(emulator: ShakerEmulator) -> None:
    refused = b"ER RANGE freq_hz = 5000.0: allowed 1 .. 2500 Hz*DAD2\r\n"
    assert answers(emulator, b"SINE 5000.0000 2.0000*3C75\n") == refused
    assert answers(emulator, b"SINE 100.0000 2.0000*C277\n") == b"ER SYNTAX checksum*E94E\r\n"


def test_emulator_alarm_refuses_start(emulator: ShakerEmulator) -> None:
    assert answers(emulator, SINE_100_2) == OK_0
    emulator.alarm("AMP_TEMP")
    assert answers(emulator, START_1) == b"ER ALARM AMP_TEMP latched*8184\r\n"
    assert answers(emulator, b"ALARM:CLR*D70D\n") == OK_0
