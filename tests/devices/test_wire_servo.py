"""Vibration-table servo: known-answer CANopen frames (arbitration id, data) for the CiA 402 objects the station uses.

From CiA 301 / 402 and config/eds/vibration_table_servo.eds, written out by hand: node 5; SDO requests on
0x605, answers on 0x585 (0x40 upload request, 0x4B / 0x43 expedited upload of 2 / 4 bytes, 0x2B / 0x23
expedited download of 2 / 4 bytes, 0x60 download confirmed, 0x80 abort with a u32 code); NMT on 0x000;
heartbeat on 0x705 (0x7F pre-operational, 0x05 operational); RPDO1 0x205 = controlword u16 + mode i8;
TPDO1 0x185 = statusword u16 + mode display i8; TPDO2 0x285 = velocity i32 (1e-6 rev/s) + position i32.
Statusword state bits (CiA 402): SWITCH ON DISABLED 0x0040, READY TO SWITCH ON 0x0031, OPERATION ENABLED
0x0037, with bit 9 (remote) set by this drive; fault 0x0008. Every bus test runs on python-can's `virtual` bus
and on `station_sim` (drivers/sim_can.py).
"""

from __future__ import annotations

import dataclasses
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import pytest

from drivers.config import load_station_config
from drivers.servo import protocol
from drivers.servo.driver import ServoLimits, VibrationTableServo
from drivers.servo.emulator import ServoEmulator
from station.clock import WallClock, host_clock

pytestmark = pytest.mark.timeout(30)

CONFIG = load_station_config(Path(__file__).parents[2] / "config" / "stations/vibration-sim.toml")
H = bytes.fromhex
WAIT_S = 2.0  # wall time a frame may take on the shared machine
# The drivers here run in wall time on threads (WallClock, python-can's virtual bus): the station file's 100 ms
# heartbeat (consumer timeout 300 ms) faults the drive when a busy host stalls them; the frames are the test.
WIRE_HEARTBEAT_MS = 500


@pytest.fixture
def channel() -> str:
    return f"wire-servo-{uuid.uuid4().hex[:8]}"


@pytest.fixture
def frame_time_s(interface: str) -> Callable[[], float]:
    """Now, on the time base of the frames' time stamps: `virtual` stamps time.time(), `station_sim` its channel's
    clock (unbound here: the host's wall clock)."""
    return time.time if interface == "virtual" else host_clock().now_s


@pytest.fixture
def drive(interface: str, channel: str) -> Iterator[ServoEmulator]:
    cfg = dataclasses.replace(CONFIG.servo, interface=interface, channel=channel, timeout_s=0.3)
    emu = ServoEmulator.from_config(cfg, WallClock())
    emu.start()
    yield emu
    emu.stop()


@pytest.fixture
def bus(interface: str, channel: str) -> Iterator[can.BusABC]:
    with can.Bus(interface=interface, channel=channel) as b:
        yield b


def _next(bus: can.BusABC, arbitration_id: int, *, after: float | None = None) -> bytes:
    """The data of the next frame with this id (received after `after`, a `frame_time_s()`, if given)."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        msg = bus.recv(timeout=0.05)
        if msg is not None and msg.arbitration_id == arbitration_id and (after is None or msg.timestamp > after):
            return bytes(msg.data)
    raise AssertionError(f"no frame 0x{arbitration_id:03X} within {WAIT_S} s")


def _sdo(bus: can.BusABC, request: bytes) -> bytes:
    bus.send(can.Message(arbitration_id=0x605, data=request, is_extended_id=False))
    return _next(bus, 0x585)


def test_statusword_decoding() -> None:
    assert protocol.state_of(0x0240) == "SWITCH ON DISABLED"
    assert protocol.state_of(0x0231) == "READY TO SWITCH ON"
    assert protocol.state_of(0x0233) == "SWITCHED ON"
    assert protocol.state_of(0x0637) == "OPERATION ENABLED"  # with bit 10, target reached
    assert protocol.state_of(0x0217) == "QUICK STOP ACTIVE"
    assert protocol.state_of(0x0208) == "FAULT"


# ---------------------------------------------------------------- the emulated drive on the bus


def test_sdo_uploads(drive: ServoEmulator, bus: can.BusABC) -> None:
    assert _sdo(bus, H("40 41 60 00 00 00 00 00")) == H("4b 41 60 00 40 02 00 00")  # 0x6041: SWITCH ON DISABLED
    assert _sdo(bus, H("40 02 65 00 00 00 00 00")) == H("43 02 65 00 04 00 00 00")  # 0x6502: profile velocity
    assert _sdo(bus, H("40 17 10 00 00 00 00 00")) == H("4b 17 10 00 64 00 00 00")  # 0x1017: the EDS default 100 ms


def test_sdo_downloads_and_an_abort(drive: ServoEmulator, bus: can.BusABC) -> None:
    # 0x60FF target velocity 10 Hz = 10 000 000 uHz
    assert _sdo(bus, H("23 ff 60 00 80 96 98 00")) == H("60 ff 60 00 00 00 00 00")
    assert _sdo(bus, H("40 ff 60 00 00 00 00 00")) == H("43 ff 60 00 80 96 98 00")
    # 0x6083 profile acceleration 0: below the EDS's low limit 1 -> abort 0x06090032 (value too low)
    assert _sdo(bus, H("23 83 60 00 00 00 00 00")) == H("80 83 60 00 32 00 09 06")
    assert _sdo(bus, H("23 83 60 00 40 42 0f 00")) == H("60 83 60 00 00 00 00 00")  # 1 rev/s^2
    # 0x6007 abort connection option (i16): 7 is beyond the EDS's high limit 3 -> 0x06090031 (value too high);
    # 1 (fault signal) is kept; 0x605A quick stop option reads 2 (the EDS default)
    assert _sdo(bus, H("2b 07 60 00 07 00 00 00")) == H("80 07 60 00 31 00 09 06")
    assert _sdo(bus, H("2b 07 60 00 01 00 00 00")) == H("60 07 60 00 00 00 00 00")
    assert _sdo(bus, H("40 07 60 00 00 00 00 00")) == H("4b 07 60 00 01 00 00 00")
    assert _sdo(bus, H("40 5a 60 00 00 00 00 00")) == H("4b 5a 60 00 02 00 00 00")


def test_nmt_pdos_and_heartbeat(drive: ServoEmulator, bus: can.BusABC, frame_time_s: Callable[[], float]) -> None:
    assert _next(bus, 0x705) in (H("7f"), H("00"))  # pre-operational (or its boot-up) before NMT start
    bus.send(can.Message(arbitration_id=0x000, data=H("01 05"), is_extended_id=False))  # NMT start node 5
    assert _next(bus, 0x705, after=frame_time_s()) == H("05")
    assert _next(bus, 0x185) == H("40 02 00")  # statusword 0x0240, mode display 0
    assert _next(bus, 0x285) == H("00 00 00 00 00 00 00 00")  # at rest, phase 0
    sent = frame_time_s()
    bus.send(can.Message(arbitration_id=0x205, data=H("06 00 03"), is_extended_id=False))  # shutdown, mode 3
    assert _next(bus, 0x185, after=sent + 0.05) == H("31 02 03")  # READY TO SWITCH ON, mode display 3
    sent = frame_time_s()
    bus.send(can.Message(arbitration_id=0x205, data=H("0f 00 03"), is_extended_id=False))  # enable operation
    assert _next(bus, 0x185, after=sent + 0.05)[:2] in (H("37 02"), H("37 06"))  # OPERATION ENABLED (+ reached)


# ---------------------------------------------------------------- the driver's frames


def test_driver_enable_and_set_frequency_frames(
    drive: ServoEmulator, bus: can.BusABC, interface: str, channel: str
) -> None:
    """enable(): controlword 0x0006, 0x0007, 0x000F by RPDO1 with mode 3; set_frequency(1 Hz, 0.5 Hz/s):
    0x6083 = 0x6084 = 500 000 (1e-6 rev/s^2), 0x60FF = 1 000 000 uHz by SDO; the reading is TPDO2's velocity."""
    cfg = dataclasses.replace(
        CONFIG.servo, interface=interface, channel=channel, timeout_s=0.3, heartbeat_ms=WIRE_HEARTBEAT_MS
    )
    servo = VibrationTableServo(cfg, ServoLimits.from_config(CONFIG), WallClock())
    servo.open()
    try:
        frames: list[tuple[int, bytes]] = []

        def record(until_s: float) -> None:
            while time.monotonic() < until_s:
                msg = bus.recv(timeout=0.02)
                if msg is not None and msg.arbitration_id in (0x205, 0x605):
                    frames.append((msg.arbitration_id, bytes(msg.data)))

        record(time.monotonic() + 0.1)
        frames.clear()
        servo.enable()
        record(time.monotonic() + 0.1)
        rpdo = [data for cob, data in frames if cob == 0x205]
        assert [H("06 00 03"), H("07 00 03"), H("0f 00 03")] == [d for d in rpdo if d[0] in (0x06, 0x07, 0x0F)][-3:]
        frames.clear()
        reading = servo.set_frequency(1.0, 0.5)
        record(time.monotonic() + 0.1)
        sdo = [data for cob, data in frames if cob == 0x605]
        assert H("23 83 60 00 20 a1 07 00") in sdo and H("23 84 60 00 20 a1 07 00") in sdo
        assert H("23 ff 60 00 40 42 0f 00") in sdo
        tpdo2 = _next(bus, 0x285)
        assert reading is not None and reading.freq_hz == pytest.approx(1.0, abs=1e-3)
        assert int.from_bytes(tpdo2[:4], "little", signed=True) == pytest.approx(1_000_000, abs=1000)
    finally:
        servo.close()
