"""Station config loader: the shipped files load with the documented values; every kind of
bad input raises ConfigError naming the file, the key, the value and what is allowed."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from drivers.config import ConfigError, load_station_config

CONFIG_DIR = Path(__file__).parents[2] / "config"
REAL = CONFIG_DIR / "stations" / "vibration.toml"
SIM = CONFIG_DIR / "stations/vibration-sim.toml"
EDS = CONFIG_DIR / "eds" / "vibration_table_servo.eds"

pytestmark = pytest.mark.timeout(10)


def test_real_station_file() -> None:
    cfg = load_station_config(REAL)
    assert not cfg.simulated
    assert cfg.station.A0_m == 0.03 and cfg.station.g_mps2 == 9.8016093
    assert cfg.station.latitude_deg == 39.94 and cfg.station.earth_rate_radps == 7.292115e-5
    assert cfg.station.pulses_per_rev == 16384 and cfg.station.timer_tick_s == 50e-9
    lim = cfg.limits
    assert (lim.freq_min_hz, lim.freq_max_hz) == (0.1, 10.0)
    assert (lim.accel_min_g, lim.accel_max_g) == (0.001, 12.5)
    assert lim.displacement_max_m == 0.03 and lim.payload_max_kg == 10.0
    assert lim.payload_size_mm == (200.0, 200.0, 220.0)
    assert cfg.servo.interface == "socketcan" and cfg.servo.channel == "can0"
    assert cfg.servo.eds == EDS.resolve()
    assert cfg.grating.port == "/dev/ttyUSB0" and cfg.indexing_head.port == "/dev/ttyUSB3"
    assert isinstance(cfg.servo.timeout_s, float) and isinstance(cfg.servo.node_id, int)


def test_sim_station_file_leaves_ports_to_the_emulators() -> None:
    cfg = load_station_config(SIM)
    assert cfg.simulated and cfg.servo.interface == "virtual"
    assert cfg.grating.port is None and cfg.indexing_head.port is None
    filled = cfg.with_serial_ports(grating="/dev/pts/7", indexing_head="/dev/pts/8")
    assert filled.grating.port == "/dev/pts/7" and filled.indexing_head.port == "/dev/pts/8"
    assert filled.indexing_head.speed_deg_s == cfg.indexing_head.speed_deg_s
    assert filled.counter.port is None
    with pytest.raises(ConfigError, match="servo"):
        cfg.with_serial_ports(servo="/dev/pts/9")


def _variant(tmp_path: Path, source: Path, edits: list[tuple[str, str]]) -> Path:
    text = source.read_text().replace('"../eds/vibration_table_servo.eds"', f'"{EDS}"')
    for pattern, repl in edits:
        new = re.sub(pattern, repl, text, count=1, flags=re.MULTILINE)
        assert new != text, f"edit {pattern!r} did not apply"
        text = new
    path = tmp_path / "station.toml"
    path.write_text(text)
    return path


BAD = [
    # (edits to station.toml, key named, value named)
    ([(r"^node_id = 5", "node_id = 5\ncolour = 'red'")], "[servo] colour", "red"),
    ([(r"^\[payload\]", "[turntable]\nx = 1\n\n[payload]")], "turntable", "x"),
    ([(r"^\[payload\]\n(.*\n)*", "")], "[payload]", "None"),
    ([(r"^node_id = 5\n", "")], "[servo] node_id", "None"),
    ([(r"^node_id = 5", 'node_id = "5"')], "[servo] node_id", "'5'"),
    ([(r"^A0_m = 0.03", 'A0_m = "0.03"')], "[station] A0_m", "'0.03'"),
    ([(r"^baud = 115200", "baud = true")], "[reference] baud", "True"),
    ([(r"^payload_size_mm = .*", "payload_size_mm = [200, 200]")], "payload_size_mm", "200"),
    ([(r"^node_id = 5", "node_id = 128")], "[servo] node_id", "128"),
    ([(r"^freq_max_hz = 10.0", "freq_max_hz = -1.0")], "[limits] freq_max_hz", "-1.0"),
    ([(r"^latitude_deg = 39.94", "latitude_deg = 91")], "[station] latitude_deg", "91"),
    ([(r"^heartbeat_ms = 100", "heartbeat_ms = 0")], "[servo] heartbeat_ms", "0"),
    ([(r"^tpdo_event_timer_ms = 250", "tpdo_event_timer_ms = 0")], "[servo] tpdo_event_timer_ms", "0"),
    ([(r"^timeout_s = 0.5", "timeout_s = inf")], "[servo] timeout_s", "inf"),
    ([(r'^channel = "can0"', 'channel = ""')], "[servo] channel", "''"),
    ([(r"^freq_min_hz = 0.1", "freq_min_hz = 20.0")], "[limits] freq_min_hz", "20.0"),
    ([(r"^mass_kg = 4.5", "mass_kg = 12.0")], "[payload] mass_kg", "12.0"),
    ([(r"^size_mm = .*", "size_mm = [250, 150, 180]")], "[payload] size_mm", "250"),
    ([(r"^A0_m = 0.03", "A0_m = 0.05")], "[station] A0_m", "0.05"),
    ([(r'^port = "/dev/ttyUSB1"\n', "")], "[reference] port", "None"),
    ([(r"^eds = .*", 'eds = "eds/missing.eds"')], "[servo] eds", "missing.eds"),
    ([(r"^\[station\]", "simulated = true\n\n[station]")], "[servo] interface", "socketcan"),
    ([(r"^\[station\]", "simulated = 1\n\n[station]")], "simulated", "1"),
    ([(r"^\[limits\]", "[limits")], "<syntax>", "line"),
]


@pytest.mark.parametrize(("edits", "key", "value"), BAD)
def test_bad_input_names_file_key_value_and_allowed(
    tmp_path: Path, edits: list[tuple[str, str]], key: str, value: str
) -> None:
    path = _variant(tmp_path, REAL, edits)
    with pytest.raises(ConfigError) as info:
        load_station_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    assert key in info.value.key
    assert value in repr(info.value.value)
    assert "allowed" in message and info.value.allowed


def test_a_good_variant_loads(tmp_path: Path) -> None:
    """The variants above fail because of their edit, not because of the copy."""
    cfg = load_station_config(_variant(tmp_path, REAL, []))
    assert cfg.servo.eds == EDS


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="readable file"):
        load_station_config(tmp_path / "nope.toml")
