"""Temperature chamber: known-answer EI-Bisynch messages from the protocol in drivers.temperature_chamber.driver.

Read [EOT] G G U U C1 C2 [ENQ] (address 01: `0011`); reply [STX] C1 C2 <data> [ETX] (BCC), or [EOT] for no
such parameter. Write [EOT] G G U U [STX] C1 C2 <data> [ETX] (BCC); reply [ACK] or [NAK]. BCC: the XOR of
every byte after STX up to and including ETX (worked out by hand for each message below).
"""

from __future__ import annotations

import contextlib

import pytest
from wire import FrozenClock, answers, driver_on

from drivers.errors import ChecksumError, DeviceFault, LimitError
from drivers.temperature_chamber.driver import ChamberStatus, TemperatureChamber
from drivers.temperature_chamber.emulator import ChamberEmulator, ChamberFault
from drivers.world import SimStation

EOT, ACK, NAK = b"\x04", b"\x06", b"\x15"
READ_PV, READ_SL, READ_SP, READ_RR = b"\x040011PV\x05", b"\x040011SL\x05", b"\x040011SP\x05", b"\x040011RR\x05"
READ_SW, READ_II, READ_XX = b"\x040011SW\x05", b"\x040011II\x05", b"\x040011XX\x05"
PV_23_45 = b"\x02PV23.45\x03\x2b"
WRITE_SL_35 = b"\x040011\x02SL35.00\x03\x34"
WRITE_SL_500 = b"\x040011\x02SL500.00\x03\x07"
WRITE_RR_1 = b"\x040011\x02RR1.00\x03\x1c"


def _chamber_on(
    transcript: list[tuple[bytes, bytes]], retries: int = 2
) -> contextlib.AbstractContextManager[TemperatureChamber]:
    """The driver on a port that plays `transcript`."""
    return driver_on(transcript, lambda port: TemperatureChamber(port, timeout_s=0.3, retries=retries))


def test_read_the_product_temperature() -> None:
    with _chamber_on([(READ_PV, PV_23_45)]) as chamber:
        assert chamber.temperature_c() == 23.45


def test_a_broken_sensor_and_an_unknown_parameter_are_device_faults() -> None:
    with _chamber_on([(READ_PV, b"\x02PVS.br\x03\x68")]) as chamber, pytest.raises(DeviceFault, match="sensor break"):
        chamber.temperature_c()
    with _chamber_on([(READ_II, EOT)]) as chamber, pytest.raises(DeviceFault, match="not known"):
        chamber.identity()


def test_write_the_setpoint_and_a_refusal() -> None:
    with _chamber_on([(WRITE_SL_35, ACK)]) as chamber:
        chamber.set_setpoint(35.0)
    with _chamber_on([(WRITE_SL_35, NAK)]) as chamber, pytest.raises(DeviceFault, match="NAK"):
        chamber.set_setpoint(35.0)


def test_a_setpoint_beyond_the_station_limits_sends_nothing() -> None:
    with _chamber_on([]) as chamber, pytest.raises(LimitError):
        chamber.set_setpoint(100.0)  # the driver's default limit is 80 deg C


def test_a_reply_with_a_bad_bcc_is_a_checksum_error_and_read_again() -> None:
    damaged = PV_23_45[:-1] + b"\x2a"
    with _chamber_on([(READ_PV, damaged), (READ_PV, PV_23_45)]) as chamber:
        assert chamber.temperature_c() == 23.45
    with _chamber_on([(READ_PV, damaged)], retries=0) as chamber, pytest.raises(ChecksumError):
        chamber.temperature_c()


def test_status_word_bits() -> None:
    """SW >0010: bit 4, the set point ramping; >0001: bit 0, over-temperature (AL1)."""
    transcript = [
        (READ_SW, b"\x02SW>0010\x03\x38"),
        (READ_PV, PV_23_45),
        (READ_SL, b"\x02SL35.00\x03\x34"),
        (READ_SP, b"\x02SP21.00\x03\x2d"),
    ]
    with _chamber_on(transcript) as chamber:
        assert chamber.status() == ChamberStatus(23.45, 35.0, 21.0, (), True)
    with _chamber_on([(READ_SW, b"\x02SW>0001\x03\x38")]) as chamber, pytest.raises(DeviceFault) as info:
        chamber.check_alarms()
    assert info.value.value == "over-temperature (AL1)"


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> ChamberEmulator:
    return ChamberEmulator(SimStation(clock=FrozenClock()), address=1)  # at ambient, 20 deg C


def test_emulator_reads(emulator: ChamberEmulator) -> None:
    assert answers(emulator, READ_SL) == b"\x02SL20.00\x03\x30"
    assert answers(emulator, READ_SP) == b"\x02SP20.00\x03\x2c"
    assert answers(emulator, READ_RR) == b"\x02RR0.00\x03\x1d"
    assert answers(emulator, READ_SW) == b"\x02SW>0000\x03\x39"
    assert answers(emulator, READ_II) == b"\x02II>2408\x03\x33"
    assert answers(emulator, READ_XX) == EOT


def test_emulator_writes_and_the_ramp(emulator: ChamberEmulator) -> None:
    assert answers(emulator, WRITE_SL_500) == NAK  # beyond the controller's set-point range
    assert answers(emulator, WRITE_SL_35[:-1] + b"\x35") == NAK  # bad BCC
    assert answers(emulator, WRITE_RR_1) == ACK
    assert answers(emulator, WRITE_SL_35) == ACK
    assert answers(emulator, READ_SL) == b"\x02SL35.00\x03\x34"
    assert answers(emulator, READ_SW) == b"\x02SW>0010\x03\x38"  # ramping at 1 deg C/min
    emulator.clock.advance_s(60.0)
    assert answers(emulator, READ_SP) == b"\x02SP21.00\x03\x2d"


def test_emulator_sensor_break(emulator: ChamberEmulator) -> None:
    emulator.inject(ChamberFault.SENSOR_BREAK, count=None)
    assert answers(emulator, READ_PV) == b"\x02PVS.br\x03\x68"
    assert answers(emulator, READ_SW) == b"\x02SW>0004\x03\x3d"
