"""The station's devices opened from its configuration: one code path for hardware and emulators."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from drivers.config import load_station_config
from drivers.errors import Disconnected, InterlockError
from drivers.station import StationDevices, simulated_station
from station.twin.config import default_twin

CONFIG_DIR = Path(__file__).parents[2] / "config"
SIM = load_station_config(CONFIG_DIR / "stations/vibration-sim.toml")
REAL = load_station_config(CONFIG_DIR / "stations" / "vibration.toml")

pytestmark = pytest.mark.timeout(60)


# The same drivers on the discrete-event station (sim:// lines) and on the paced transports a real tty and bus
# behave like (VirtualClock, ptys, python-can's virtual bus).
PORT_PREFIX = {"sim": "sim://", "pty": "/dev/pts/"}
# On ptys the lines carry their baud in wall time: 19-byte grating frames at 3 Mbaud carry about 15 800 samples per
# wall second, so a 5 kHz record keeps up at 2x; the drive and its driver, alone in wall time on a shared machine,
# hear each other's heartbeat every 500 ms (host stalls of 0.6-0.7 s are seen).
PTY_SPEED = 2.0
PTY = dataclasses.replace(SIM, servo=dataclasses.replace(SIM.servo, heartbeat_ms=500))


@pytest.fixture(params=["sim", "pty"])
def sim(request):
    deterministic = request.param == "sim"
    config, speed = (SIM, None) if deterministic else (PTY, PTY_SPEED)
    with simulated_station(config, default_twin(), seed=2, speed=speed, deterministic=deterministic) as s:
        s.transport = request.param
        yield s


def test_every_driver_talks_to_its_emulator_through_the_configured_port(sim) -> None:
    d = sim.devices
    ports = {name: emu.port for name, emu in sim.emulators.items() if name != "servo"}
    assert ports == {"grating": d.grating.port, "reference": d.reference.port, "counter": d.counter.port,
                     "indexing_head": d.head.port}  # fmt: skip
    assert all(p.startswith(PORT_PREFIX[sim.transport]) for p in ports.values())
    assert d.servo.state == "SWITCH ON DISABLED"
    assert d.counter.status()["state"] == "idle"
    assert d.move_index(36.0) == pytest.approx(36.0, abs=SIM.indexing_head.settle_tol_deg)


def test_the_head_never_moves_while_the_crank_turns(sim) -> None:
    d = sim.devices
    d.set_vibration(2.0)
    before = d.index_position_deg()
    with pytest.raises(InterlockError, match="not permitted by the interlock"):
        d.move_index(90.0)
    assert d.index_position_deg() == before
    d.set_vibration(0.0)
    assert d.table_at_rest() and d.move_index(90.0) == pytest.approx(90.0, abs=1e-3)


def test_capture_motion_puts_grating_and_reference_crossings_on_one_time_base(sim) -> None:
    d = sim.devices
    d.set_vibration(5.0)
    m = d.capture_motion(1.0)
    assert len(m.t_s) == 5000 and np.all(np.diff(m.t_s) > 0)
    # At each reference crossing (psi = 0, physics.md) the table is at mid-stroke moving up:
    # z crosses its mean upwards there, to within one sample (2 ms: 0.06 rad of phase at 5 Hz).
    assert 4 <= len(m.reference_t_s) <= 6
    for t in m.reference_t_s:
        i = np.searchsorted(m.t_s, t)
        if 0 < i < len(m.t_s):
            assert m.z_m[i - 1] <= 2 * math.pi * 5 * 0.03 * 2e-4 and m.z_m[i] >= -2 * math.pi * 5 * 0.03 * 2e-4


def test_a_station_that_is_not_there_fails_to_open_naming_the_device() -> None:
    # The real station's file on this machine: no CAN interface can0, no /dev/ttyUSB*.
    with pytest.raises(Disconnected, match="vibration table servo: cannot open CAN socketcan:can0"):
        StationDevices.open(REAL)
    missing = dataclasses.replace(SIM, counter=dataclasses.replace(SIM.counter, port=None))
    with pytest.raises(InterlockError, match="no serial port configured for grating, reference, counter"):
        StationDevices.open(missing)


def test_a_real_configuration_is_not_simulated() -> None:
    with pytest.raises(InterlockError, match="real station's configuration"):
        simulated_station(REAL, default_twin())


@pytest.mark.parametrize("stop", ["emergency_stop", "safe_stop"])
def test_the_station_stops_reach_a_further_device_that_moves(stop: str) -> None:
    shaker_station = load_station_config(CONFIG_DIR / "stations/shaker-sim.toml")
    with simulated_station(shaker_station, default_twin(), seed=3, speed=20.0) as s:
        shaker = s.devices.device("shaker")
        shaker.set_sine(20.0, 1.0)
        shaker.start(0.5)
        assert shaker.status().running
        getattr(s.devices, stop)()
        s.devices.clock.sleep_s(2.5)  # a safe stop ramps down over up to 2 s
        assert shaker.status().state == "IDLE" and not shaker.status().running
