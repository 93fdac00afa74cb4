"""A station without a vibration table (the shipped tumble and shaker stations): its file leaves out the table's
four sections together, it opens no CAN bus, planning refuses any vibration, window or grating step before
anything moves, and its stops, reset and status reach what it has (the head and its further devices)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from drivers.config import TABLE_SECTIONS, ConfigError, load_station_config
from drivers.errors import InterlockError
from drivers.station import simulated_station
from station.cli.cli import main
from station.engine.protocols import Stoppable
from station.twin.config import default_twin

CONFIG_DIR = Path(__file__).parents[2] / "config"
TUMBLE = CONFIG_DIR / "stations/tumble-sim.toml"
SIM = CONFIG_DIR / "stations/vibration-sim.toml"

pytestmark = pytest.mark.timeout(60)


def test_the_tumble_station_has_the_head_and_its_devices_and_no_table() -> None:
    cfg = load_station_config(TUMBLE)
    assert all(getattr(cfg, name) is None for name in TABLE_SECTIONS)
    assert cfg.core_devices() == ("indexing_head",)
    assert cfg.station_model().devices == {"indexing_head", "voltmeter", "temperature_chamber"}
    with pytest.raises(ConfigError, match=r"counter = '/dev/pts/9'.*allowed: one of indexing_head, voltmeter"):
        cfg.with_serial_ports(counter="/dev/pts/9")
    assert load_station_config(SIM).core_devices() == (*TABLE_SECTIONS, "indexing_head")


@pytest.mark.parametrize("left_out", TABLE_SECTIONS)
def test_a_table_with_a_section_missing_is_refused_naming_it(tmp_path: Path, left_out: str) -> None:
    text = SIM.read_text().replace('"../eds/', f'"{CONFIG_DIR}/eds/')
    cut = re.sub(rf"^\[{left_out}\]\n(?:[^\[\n].*\n|\n)*", "", text, count=1, flags=re.MULTILINE)
    assert cut != text
    path = tmp_path / "station.toml"
    path.write_text(cut)
    with pytest.raises(ConfigError) as info:
        load_station_config(path)
    assert info.value.key == f"[{left_out}]" and info.value.value is None
    assert "the vibration table's sections come together: servo, grating, reference, counter" in str(info.value)


@pytest.mark.parametrize("procedure", ["integral_precession", "integral_precession.frequency_stability"])
def test_a_vibration_procedure_on_a_station_without_a_table_is_refused_in_planning(
    tmp_path: Path, procedure: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", procedure, "--station", "tumble-sim", "--out", str(tmp_path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert re.search(r"device = '(counter|servo)' is not allowed: a device of this station: indexing_head", err), err
    assert not list(tmp_path.iterdir())  # nothing stored: refused before anything moves


def test_a_station_without_a_table_stops_resets_and_reports_what_it_has() -> None:
    with simulated_station(load_station_config(TUMBLE), default_twin(), seed=4) as sim:
        devices = sim.devices
        assert sim.can_channel == "" and "servo" not in sim.emulators
        assert devices.table_at_rest()
        with pytest.raises(InterlockError, match=r"tumble-sim.toml has no vibration table \(no \[servo\]"):
            devices.set_vibration(1.0)
        with pytest.raises(InterlockError, match="no vibration table"):
            devices.measure_window(10)
        assert devices.move_index(90.0) == pytest.approx(90.0, abs=0.001)  # [indexing_head] settle_tol_deg
        devices.emergency_stop()
        assert devices.status() == {"drive_state": None, "drive_fault": None, "head_held": True}
        devices.reset()
        assert devices.status()["head_held"] is False
        assert not any(isinstance(d, Stoppable) for d in devices.extra.values())  # the chamber holds its set point
        devices.safe_stop()
        assert devices.safe_stop_bound_s() == 1.0
