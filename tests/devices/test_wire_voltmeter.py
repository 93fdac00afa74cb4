"""Precision voltmeter: known-answer SCPI lines from the protocol in drivers.voltmeter.driver's docstring.

Commands end in LF; a query answers one line; readings are NR3 (`+1.23456789E+00`), comma-separated;
an overloaded input reads +9.9E37; errors queue as `<code>,"<text>"` and SYST:ERR? answers
`0,"No error"` when the queue is empty. SCPI has no checksum: damage is caught by the strict format.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from wire import FrozenClock, answers, scripted_port

from drivers.errors import DeviceFault, FrameError, LimitError
from drivers.voltmeter.driver import Voltmeter
from drivers.voltmeter.emulator import VoltmeterEmulator, VoltmeterFault
from drivers.world import SimStation

NO_ERROR = b'0,"No error"\n'
CONFIGURE_20V_10PLC_3 = [
    (b":SYST:ERR?\n", NO_ERROR),
    (b":CONF:VOLT:DC\n", b""),
    (b":SENS:VOLT:DC:RANG 20\n", b""),
    (b":SENS:VOLT:DC:NPLC 10\n", b""),
    (b":SAMP:COUN 3\n", b""),
]
READINGS = b"+1.00000000E+00,-2.50000000E-01,+9.99999999E-03\n"
NR3_LINE = re.compile(rb"[+-]\d\.\d{8}E[+-]\d{2}\n")  # one reading, 9 significant digits


def _meter(port: str, retries: int = 2) -> Voltmeter:
    return Voltmeter(port, line_hz=50.0, timeout_s=0.3, retries=retries, clock=FrozenClock())


def test_configure_then_read() -> None:
    transcript = [*CONFIGURE_20V_10PLC_3, (b":SYST:ERR?\n", NO_ERROR), (b":READ?\n", READINGS)]
    with scripted_port(transcript) as port, _meter(port).open() as meter:
        reading = meter.measure(20.0, 10.0, 3)
    np.testing.assert_array_equal(reading.volts, [1.0, -0.25, 9.99999999e-3])


def test_a_configuration_the_instrument_refuses_is_a_device_fault() -> None:
    refused = [(b":SYST:ERR?\n", b'-222,"Data out of range"\n'), (b":SYST:ERR?\n", NO_ERROR)]
    with (
        scripted_port([*CONFIGURE_20V_10PLC_3, *refused]) as port,
        _meter(port).open() as meter,
        pytest.raises(DeviceFault, match="refused") as info,
    ):
        meter.configure(20.0, 10.0, 3)
    assert info.value.value == '-222,"Data out of range"'


def test_an_overloaded_input_is_a_device_fault() -> None:
    transcript = [*CONFIGURE_20V_10PLC_3, (b":SYST:ERR?\n", NO_ERROR), (b":READ?\n", b"+9.9E37\n")]
    with scripted_port(transcript) as port, _meter(port, retries=0).open() as meter, pytest.raises(FrameError):
        meter.measure(20.0, 10.0, 3)  # +9.9E37 alone is not 3 NR3 readings
    transcript[-1] = (b":READ?\n", b"+9.90000000E+37,+9.90000000E+37,+9.90000000E+37\n")
    with scripted_port(transcript) as port, _meter(port).open() as meter, pytest.raises(DeviceFault, match="overload"):
        meter.measure(20.0, 10.0, 3)


def test_a_damaged_reading_is_a_frame_error_and_read_again() -> None:
    transcript = [
        *CONFIGURE_20V_10PLC_3,
        (b":SYST:ERR?\n", NO_ERROR),
        (b":READ?\n", b"+1.00000000E+00,-2.5000\x8000E-01,+9.99999999E-03\n"),
        (b":READ?\n", READINGS),
    ]
    with scripted_port(transcript) as port, _meter(port).open() as meter:
        assert meter.measure(20.0, 10.0, 3).volts[1] == -0.25


def test_a_range_the_instrument_lacks_sends_nothing() -> None:
    with scripted_port([]) as port, _meter(port).open() as meter, pytest.raises(LimitError, match="no such range"):
        meter.configure(5.0, 10.0, 3)


def test_identity() -> None:
    idn = b"KEITHLEY INSTRUMENTS INC.,MODEL 2002,4230517,A20  /A02\n"
    with scripted_port([(b"*IDN?\n", idn)]) as port, _meter(port).open() as meter:
        assert meter.identity() == idn.decode().rstrip("\n")


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> VoltmeterEmulator:
    return VoltmeterEmulator(SimStation(clock=FrozenClock()), line_hz=50.0)


def test_emulator_settings_in_short_and_long_forms(emulator: VoltmeterEmulator) -> None:
    assert answers(emulator, b"*IDN?\n") == b"KEITHLEY INSTRUMENTS INC.,MODEL 2002,4230517,A20  /A02\n"
    assert answers(emulator, b":SENS:VOLT:DC:RANG 2\n:SENS:VOLT:DC:RANG?\n") == b"+2.000000E+00\n"
    assert answers(emulator, b":SENSe:VOLTage:DC:NPLCycles 10\n:VOLT:DC:NPLC?\n") == b"+1.000000E+01\n"
    assert answers(emulator, b":SAMP:COUN 5;:SAMP:COUN?\n") == b"5\n"
    assert answers(emulator, b":SYST:ERR?\n") == NO_ERROR


def test_emulator_queues_errors(emulator: VoltmeterEmulator) -> None:
    assert answers(emulator, b":SENS:VOLT:DC:NPLC 100\n:FOO:BAR\n:SAMP:COUN x\n") == b""
    queue = b'-222,"Data out of range"\n-113,"Undefined header"\n-104,"Data type error"\n' + NO_ERROR
    assert answers(emulator, b":SYST:ERR?\n:SYST:ERR?\n:SYST:ERR?\n:SYST:ERR?\n") == queue


def test_emulator_read_answers_after_its_aperture(emulator: VoltmeterEmulator) -> None:
    """1 PLC at 50 Hz, 2 conversions per reading (auto-zero): the reply goes out 40 ms of station time later."""
    assert answers(emulator, b":READ?\n", poll_at_s=0.039) == b""
    assert NR3_LINE.fullmatch(answers(emulator, b"", poll_at_s=0.041))


def test_emulator_overload_reads_9_9e37(emulator: VoltmeterEmulator) -> None:
    emulator.inject(VoltmeterFault.OVERLOAD)
    assert answers(emulator, b":READ?\n", poll_at_s=0.041) == b"+9.90000000E+37\n"
