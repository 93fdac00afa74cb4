"""Gradiometer: line codec, then the real driver against its emulator over a pty and a sim:// line, the tilt coming
from the world (the twin's parasitic rotation at the crank phase of each reading's time stamp).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import pytest
from links import serve

from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout, Disconnected, FrameError
from drivers.gradiometer import driver as gm
from drivers.gradiometer import kind as gk
from drivers.gradiometer.emulator import GradiometerEmulator
from drivers.pty_link import Fault
from drivers.world import SimStation
from station.clock import VirtualClock
from station.twin.config import default_twin
from station.twin.table_tilt import ARCSEC_RAD, TiltHarmonics

pytestmark = pytest.mark.timeout(60)

# Seed 000 Table 7's table top: ax0 16.58", axs1 -0.92", axc1 0.19" (eq. 34 on the table).
AX = {"ax0": 16.58 * ARCSEC_RAD, "axs1": -0.92 * ARCSEC_RAD, "axc1": 0.19 * ARCSEC_RAD}
ABOUT_Y = TiltHarmonics(0.06 * ARCSEC_RAD, -0.46 * ARCSEC_RAD, -1.49 * ARCSEC_RAD)
NOISE_ARCSEC = 0.005
# A reading is the tilt at its stamp's phase plus noise, rounded to 0.005": within 5 sigma + half a step.
READ_TOL_ARCSEC = 5 * NOISE_ARCSEC + 0.0025
CRANK_HZ = 0.5
TIMEOUT_S = 0.3


@pytest.fixture
def rig(transport: str) -> Iterator[tuple[SimStation, GradiometerEmulator, gm.Gradiometer]]:
    world = SimStation(default_twin().with_effect("parasitic_rotation", **AX), VirtualClock(5.0), seed=4)
    world.crank.command_speed(2 * math.pi * CRANK_HZ, 1e6, world.clock.now_s())
    emu = GradiometerEmulator(world, noise_arcsec=NOISE_ARCSEC, about_y=ABOUT_Y)
    try:
        grad = gm.Gradiometer(serve(emu, transport), timeout_s=TIMEOUT_S, retries=0, clock=world.clock).open()
        try:
            yield world, emu, grad
        finally:
            grad.close()
    finally:
        emu.close()


# ---------------------------------------------------------------- codec


def test_line_roundtrip_and_checksum() -> None:
    line = gm.encode_line("!", 7, "RD", 12, "0000ABCD", "+16.580", "-0.005", "+0.000", 0)
    assert line.endswith(b"\r\n") and line.startswith(b"!07RD,12,")
    body = line[1:-5]
    assert int(line[-4:-2], 16) == sum(body) % 256
    assert gm.decode_line(line[:-2]) == (7, "RD", ["12", "0000ABCD", "+16.580", "-0.005", "+0.000", "0"])
    assert gm.decode_line(gm.encode_line("#", 1, "ID")[:-2], lead=b"#") == (1, "ID", [])


def test_bad_lines_raise_typed_errors() -> None:
    line = gm.encode_line("!", 1, "ID", "EG-3", "0001", 0.005, 600)[:-2]
    with pytest.raises(ChecksumError, match="checksum"):
        gm.decode_line(line[:-2] + b"%02X" % ((int(line[-2:], 16) + 1) % 256))
    for bad in (line[: len(line) // 2], b"#01ID*00", b"!01ID,x*ZZ", b""):
        with pytest.raises(FrameError):
            gm.decode_line(bad)


# ---------------------------------------------------------------- driver against emulator


def test_identity_and_readings_follow_the_twin(rig) -> None:
    world, _, grad = rig
    ident = grad.identify()
    assert (ident.model, ident.resolution_arcsec, ident.range_arcsec) == ("EG-3", 0.005, 600.0)
    last_n = 0
    for _ in range(12):
        r = grad.read()
        assert r.n > last_n and r.t_s <= world.clock.now_s()
        last_n = r.n
        psi = world.crank.phase_rad(r.t_s)
        x = (AX["ax0"] + AX["axs1"] * math.sin(psi) + AX["axc1"] * math.cos(psi)) / ARCSEC_RAD
        assert r.phi_x_arcsec == pytest.approx(x, abs=READ_TOL_ARCSEC)
        assert r.phi_y_arcsec == pytest.approx(float(ABOUT_Y.at(psi)) / ARCSEC_RAD, abs=READ_TOL_ARCSEC)
        assert r.phi_z_arcsec == pytest.approx(0.0, abs=READ_TOL_ARCSEC)
        # the instrument's resolution: every reading a multiple of 0.005"
        assert round(r.phi_x_arcsec / 0.005, 6) == pytest.approx(round(r.phi_x_arcsec / 0.005), abs=1e-6)
        world.clock.sleep_s(0.13)


def _bounded(call, error: type[Exception], within_s: float) -> Exception:
    t0 = time.monotonic()
    with pytest.raises(error) as info:
        call()
    assert time.monotonic() - t0 < within_s
    return info.value


def test_no_answer_is_a_timeout_and_a_retry_recovers(rig) -> None:
    _, emu, grad = rig
    emu.inject(Fault.NO_ANSWER, count=1)
    _bounded(grad.read, DeviceTimeout, TIMEOUT_S + 0.5)
    emu.inject(Fault.NO_ANSWER, count=1)
    grad.retries = 1
    assert grad.read().phi_x_arcsec > 15.0  # the second attempt is answered


@pytest.mark.parametrize(
    ("fault", "error"),
    [(Fault.GARBLE, FrameError), (Fault.TRUNCATE, FrameError), (Fault.CRC_ERROR, ChecksumError)],
)
def test_damaged_replies_are_typed_errors(rig, fault, error) -> None:
    _, emu, grad = rig
    emu.inject(fault)
    _bounded(grad.read, error, TIMEOUT_S + 0.5)
    assert grad.read().n > 0  # the line is usable again


def test_signal_loss_and_over_range_are_device_faults(rig) -> None:
    _, emu, grad = rig
    emu.inject(Fault.SIGNAL_LOSS, count=None)
    err = _bounded(grad.read, DeviceFault, TIMEOUT_S + 0.5)
    assert err.field == "status" and err.value == 2
    emu.clear_fault(Fault.SIGNAL_LOSS)
    emu.range_arcsec = 10.0  # the table top tilts 16.6" about x: beyond a 10" instrument
    err = _bounded(grad.read, DeviceFault, TIMEOUT_S + 0.5)
    assert err.field == "phi_x_arcsec" and err.value == pytest.approx(10.0)
    assert "over range" in str(err)


def test_unknown_command_and_other_addresses(rig) -> None:
    _, emu, grad = rig
    err = _bounded(lambda: grad._query("ZZ"), DeviceFault, TIMEOUT_S + 0.5)
    assert err.field == "reply" and err.value == "BADCMD"
    other = gm.Gradiometer(emu.port, address=2, timeout_s=TIMEOUT_S, retries=1)
    grad.close()
    with other.open():
        _bounded(other.identify, DeviceTimeout, 2 * TIMEOUT_S + 0.5)  # address 2 stays silent


def test_disconnect(rig) -> None:
    _, emu, grad = rig
    emu.inject(Fault.DISCONNECT)
    time.sleep(0.05)
    _bounded(grad.read, Disconnected, TIMEOUT_S + 0.5)


def test_open_checks_the_instrument_against_the_station_file(rig) -> None:
    world, emu, grad = rig
    grad.close()
    section = gk.GradiometerSection(port=emu.port, baud=115_200, address=1, resolution_arcsec=0.005, range_arcsec=60.0)
    with pytest.raises(DeviceFault) as info:
        gk.open_gradiometer(section, world.clock)
    assert info.value.field == "range_arcsec" and info.value.value == 600.0 and "60" in str(info.value)
    ok = gk.open_gradiometer(gk.GradiometerSection(emu.port, 115_200, 1, 0.005, 600.0), world.clock)
    assert ok.read().n > 0
    ok.close()
