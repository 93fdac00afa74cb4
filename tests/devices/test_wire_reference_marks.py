"""Reference marks monitor: known-answer lines from the NMEA-style protocol in drivers.reference_marks.driver.

`$` body `*` hh CR LF, hh the XOR of the body's bytes as two upper-case hex digits (worked out by hand
for each line below); time stamps as 8 hex digits of 50 ns ticks: 1.1 s = 014FB180, 1.2 s = 016E3600,
1.3 s = 018CBA80, 1.0 s = 01312D00, 2.0 s = 02625A00.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from wire import FrozenClock, answers, scripted_port

from drivers.errors import ChecksumError, DeviceFault
from drivers.reference_marks.driver import ReferenceMarks
from drivers.reference_marks.emulator import ReferenceEmulator

START, STOP, STATUS_Q = b"$START*40\r\n", b"$STOP*18\r\n", b"$STATUS?*2B\r\n"
OK_START, OK_STOP = b"$OK,START*68\r\n", b"$OK,STOP*30\r\n"
Z0, Z1, Z2 = b"$Z,0,014FB180*62\r\n", b"$Z,1,016E3600*1C\r\n", b"$Z,2,018CBA80*19\r\n"
Z3_AT_1_3S = b"$Z,3,018CBA80*18\r\n"
ALARM_SIGNAL_LOSS = b"$A,1,01406F40*01\r\n"  # at 1.05 s
TICK_S = 50e-9


def _monitor(port: str) -> ReferenceMarks:
    return ReferenceMarks(port, timeout_s=0.3, silence_s=0.5, clock=FrozenClock(1.0))


def test_start_and_crossings() -> None:
    with scripted_port([(START, OK_START + Z0 + Z1)]) as port, _monitor(port).open() as ref:
        ref.start()
        first, second = ref.next_crossing(timeout_s=1.0), ref.next_crossing(timeout_s=1.0)
        ref.reporting = False  # the transcript has no STOP for close() to send
    assert (first.n, second.n) == (0, 1)
    assert first.t_s == pytest.approx(1.1, abs=TICK_S) and second.t_s == pytest.approx(1.2, abs=TICK_S)


def test_frequency_from_consecutive_crossings() -> None:
    """Three crossings 0.1 s apart: 10 Hz, sigma_f / f = 0 (seed 000 section 6.1.2)."""
    with scripted_port([(START, OK_START + Z0 + Z1 + Z2), (STOP, OK_STOP)]) as port, _monitor(port).open() as ref:
        ref.start()
        estimate = ref.measure_frequency(periods=2, timeout_s=1.0)
        ref.stop()
    assert estimate.f_hz == pytest.approx(10.0, rel=1e-6) and estimate.sigma_rel == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(estimate.periods_s, [0.1, 0.1], atol=2 * TICK_S)


def test_a_gap_in_crossing_numbers_counts_lost_crossings() -> None:
    with scripted_port([(START, OK_START + Z0 + Z3_AT_1_3S)]) as port, _monitor(port).open() as ref:
        ref.start()
        ref.next_crossing(timeout_s=1.0)
        assert ref.next_crossing(timeout_s=1.0).n == 3
        ref.reporting = False
    assert ref.lost_crossings == 2


def test_status_query() -> None:
    with scripted_port([(STATUS_Q, b"$ST,1,0,42,01312D00*75\r\n")]) as port, _monitor(port).open() as ref:
        assert ref.status() == {"reporting": True, "alarm": 0, "crossings": 42, "ticks": 0x01312D00}


def test_an_error_reply_is_a_device_fault() -> None:
    transcript = [(START, b"$ERR,BADCMD*64\r\n")]
    with (
        scripted_port(transcript) as port,
        ReferenceMarks(port, timeout_s=0.3, retries=0).open() as ref,
        pytest.raises(DeviceFault, match="rejected"),
    ):
        ref.start()


def test_an_alarm_line_is_a_device_fault() -> None:
    with scripted_port([(START, OK_START + ALARM_SIGNAL_LOSS)]) as port, _monitor(port).open() as ref:
        ref.start()
        with pytest.raises(DeviceFault, match="signal loss") as info:
            ref.next_crossing(timeout_s=1.0)
        ref.reporting = False
    assert (info.value.field, info.value.value) == ("alarm", 1)


def test_a_crossing_with_a_bad_checksum_is_a_checksum_error() -> None:
    with scripted_port([(START, OK_START + b"$Z,0,014FB180*63\r\n")]) as port, _monitor(port).open() as ref:
        ref.start()
        with pytest.raises(ChecksumError):
            ref.next_crossing(timeout_s=1.0)
        ref.reporting = False


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> ReferenceEmulator:
    marks_s = np.array([1.1, 1.2])  # the twin's crossings, as the world reports them

    def crossings(t0_s: float, t1_s: float) -> np.ndarray:
        return marks_s[(marks_s > t0_s) & (marks_s <= t1_s)]

    return ReferenceEmulator(SimpleNamespace(clock=FrozenClock(1.0), reference_crossings_s=crossings))


def test_emulator_commands(emulator: ReferenceEmulator) -> None:
    assert answers(emulator, STATUS_Q) == b"$ST,0,0,0,01312D00*42\r\n"
    assert answers(emulator, b"$STATUS?*2C\r\n") == b"$ERR,CHECKSUM*64\r\n"
    assert answers(emulator, b"$BOGUS*4C\r\n") == b"$ERR,BADCMD*64\r\n"
    assert answers(emulator, STOP) == OK_STOP


def test_emulator_reports_crossings_and_heartbeats(emulator: ReferenceEmulator) -> None:
    assert answers(emulator, START) == OK_START
    assert answers(emulator, b"", poll_at_s=1.25) == Z0 + Z1
    assert answers(emulator, b"", poll_at_s=2.0) == b"$H,02625A00*16\r\n"  # 1 s of station time after START
