"""The control channel's `inject` (a test hook): a served simulated station arms one fault in an emulator for a
test outside its process (tests/web/test_operators_day.py); a real station, whose devices have no emulators,
refuses it."""

from __future__ import annotations

import pytest

from drivers.errors import DriverError
from station.cli.control import ControlServer


def _inject(server: ControlServer, device: str, fault: str) -> dict:
    return server.handle({"cmd": "inject", "args": {"device": device, "fault": fault}}, "test", record=False)


def test_inject_arms_one_fault_in_the_named_emulator(make_rig) -> None:
    rig = make_rig(speed=None)
    server = ControlServer(rig.controller, "tcp://127.0.0.1:*", token="s3cret")
    try:
        armed = _inject(server, "counter", "crc_error")
        assert armed == {"ok": True, "result": {"device": "counter", "fault": "crc_error"}}
        with rig.sim.devices.clock.party("test"):
            with pytest.raises(DriverError):
                rig.sim.devices.counter.arm(1000)  # its reply carries a wrong checksum (an ARM is not retried)
            rig.sim.devices.counter.abort()
            assert rig.sim.devices.counter.measure(1000).pulses == 1000  # one occurrence only
    finally:
        server.close()


def test_inject_names_what_it_cannot_take(make_rig) -> None:
    rig = make_rig(speed=None)
    server = ControlServer(rig.controller, "tcp://127.0.0.1:*", token="s3cret")
    try:
        unknown = _inject(server, "toaster", "crc_error")
        assert unknown["error"]["type"] == "ControlError" and "counter" in unknown["error"]["message"]
        assert "'meltdown'" in _inject(server, "counter", "meltdown")["error"]["message"]
    finally:
        server.close()


def test_a_real_station_refuses_inject(make_rig) -> None:
    rig = make_rig(speed=None)
    rig.sim.devices.inject_fault = None  # as StationDevices.open leaves it on a real station
    server = ControlServer(rig.controller, "tcp://127.0.0.1:*", token="s3cret")
    try:
        refused = _inject(server, "counter", "crc_error")
        assert refused["error"]["message"] == "inject: a real station takes no injected faults"
    finally:
        server.close()
