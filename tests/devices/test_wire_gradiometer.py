"""Gradiometer: known-answer lines from the addressed ASCII protocol in drivers.gradiometer.driver's docstring.

Request `#<aa><CMD>*<cs>` CR LF, reply `!<aa><CMD>,<field>,...*<cs>` CR LF; cs the byte sum of everything
between the lead and the `*`, mod 256, as two upper-case hex digits (worked out by hand for each line below).
RD fields: n, ticks (8 hex digits of 50 ns: 1.0 s = 01312D00), phi_x, phi_y, phi_z (arcsec, 3 decimals), status.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from wire import FrozenClock, answers, scripted_port

from drivers.errors import ChecksumError, DeviceFault
from drivers.gradiometer.driver import Gradiometer, Identity
from drivers.gradiometer.emulator import GradiometerEmulator
from drivers.pty_link import Fault
from station.twin.table_tilt import ARCSEC_RAD, TiltHarmonics

ID_Q, RD_Q = b"#01ID*EE\r\n", b"#01RD*F7\r\n"
READING_7 = b"!01RD,7,01312D00,+1.250,-0.005,+0.000,0*5B\r\n"
TICK_S = 50e-9


def _grad(port: str, retries: int = 2) -> Gradiometer:
    return Gradiometer(port, address=1, timeout_s=0.3, retries=retries, clock=FrozenClock(1.0))


def test_identity() -> None:
    with scripted_port([(ID_Q, b"!01ID,EG-3,0042,0.005,60*A9\r\n")]) as port, _grad(port).open() as grad:
        assert grad.identify() == Identity("EG-3", "0042", 0.005, 60.0)


def test_reading() -> None:
    with scripted_port([(RD_Q, READING_7)]) as port, _grad(port).open() as grad:
        r = grad.read()
    assert (r.n, r.phi_x_arcsec, r.phi_y_arcsec, r.phi_z_arcsec) == (7, 1.25, -0.005, 0.0)
    assert r.t_s == pytest.approx(1.0, abs=TICK_S)


def test_over_range_names_the_axis() -> None:
    transcript = [(RD_Q, b"!01RD,8,01312D00,+61.000,-0.005,+0.000,1*8C\r\n")]
    with scripted_port(transcript) as port, _grad(port).open() as grad, pytest.raises(DeviceFault) as info:
        grad.read()
    assert (info.value.field, info.value.value) == ("phi_x_arcsec", 61.0)


def test_sensor_fault_status() -> None:
    transcript = [(RD_Q, b"!01RD,9,01312D00,+0.000,+0.000,+0.000,2*50\r\n")]
    with scripted_port(transcript) as port, _grad(port).open() as grad, pytest.raises(DeviceFault) as info:
        grad.read()
    assert (info.value.field, info.value.value) == ("status", 2)


def test_an_error_reply_is_a_device_fault() -> None:
    transcript = [(RD_Q, b"!01ER,BADCMD*BF\r\n")]
    with scripted_port(transcript) as port, _grad(port).open() as grad, pytest.raises(DeviceFault) as info:
        grad.read()
    assert info.value.value == "BADCMD"


def test_a_bad_checksum_is_a_checksum_error_and_the_request_is_sent_again() -> None:
    damaged = READING_7.replace(b"*5B", b"*5C")
    with scripted_port([(RD_Q, damaged), (RD_Q, READING_7)]) as port, _grad(port).open() as grad:
        assert grad.read().n == 7
    with (
        scripted_port([(RD_Q, damaged)]) as port,
        _grad(port, retries=0).open() as grad,
        pytest.raises(ChecksumError),
    ):
        grad.read()


def test_another_instruments_reply_is_skipped() -> None:
    other = b"!02RD,7,01312D00,+9.000,+9.000,+9.000,0*68\r\n"
    with scripted_port([(RD_Q, other + READING_7)]) as port, _grad(port).open() as grad:
        assert grad.read().phi_x_arcsec == 1.25


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> GradiometerEmulator:
    """No noise, no twin tilt about x; +1.25 arcsec about y and -700 arcsec (beyond the 600 arcsec range) about z."""
    world = SimpleNamespace(clock=FrozenClock(1.0), rng=np.random.default_rng(0),
                            crank=SimpleNamespace(phase_rad=lambda t_s: 0.0),
                            twin=SimpleNamespace(param=lambda effect, key: 0.0))  # fmt: skip
    return GradiometerEmulator(world, noise_arcsec=0.0, about_y=TiltHarmonics(a0_rad=1.25 * ARCSEC_RAD))


def test_emulator_identity_and_reading(emulator: GradiometerEmulator) -> None:
    assert answers(emulator, ID_Q) == b"!01ID,EG-3,0001,0.005,600*D4\r\n"
    assert answers(emulator, RD_Q) == b"!01RD,1,01312D00,+0.000,+1.250,+0.000,0*4E\r\n"
    assert answers(emulator, RD_Q) == b"!01RD,2,01312D00,+0.000,+1.250,+0.000,0*4F\r\n"


def test_emulator_over_range_is_clipped_with_status_1(emulator: GradiometerEmulator) -> None:
    emulator.about_z = TiltHarmonics(a0_rad=-700.0 * ARCSEC_RAD)
    assert answers(emulator, RD_Q) == b"!01RD,1,01312D00,+0.000,+1.250,-600.000,1*B7\r\n"


def test_emulator_errors(emulator: GradiometerEmulator) -> None:
    assert answers(emulator, b"#01XX*11\r\n") == b"!01ER,BADCMD*BF\r\n"
    assert answers(emulator, b"#01RD*F8\r\n") == b"!01ER,CHECKSUM*77\r\n"
    assert answers(emulator, b"#02RD*F8\r\n") == b""  # another instrument's request
    emulator.inject(Fault.CRC_ERROR)
    assert answers(emulator, ID_Q) == b"!01ID,EG-3,0001,0.005,600*D5\r\n"
