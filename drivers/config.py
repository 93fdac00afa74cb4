"""Typed loader for the station configuration (config/stations/vibration.toml, config/stations/vibration-sim.toml).

Every section is declared once, as a settings dataclass (station.validation, pydantic); every key
is required, typed and range-checked. Bad input raises ConfigError naming the file, the key, the value
and what is allowed. Paths (the servo EDS) are relative to the config file's
directory. A simulated station (`simulated = true` at the top level) may leave
serial ports out: the emulators create them at run time (`with_serial_ports`).
A station without a vibration table (a tumble or a shaker station) leaves out the
table's four sections together (TABLE_SECTIONS); its procedures may then use no
vibration, window or grating step (planning refuses them: station.engine.context).
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_args

from pydantic import Field, ValidationError
from pydantic.fields import FieldInfo

from drivers.registry import device_kinds
from station import constants
from station.engine.context import StationModel
from station.errors import InputError
from station.session import StationInfo
from station.validation import defects, field_allowed, field_optional, in_range, settings, settings_fields, spec

SERIAL_SECTIONS = ("grating", "reference", "counter", "indexing_head")
# The vibration table's devices: a station file has all four sections or none (a tumble or shaker station
# without a crank table has the indexing head and its further devices only).
TABLE_SECTIONS = ("servo", "grating", "reference", "counter")


class ConfigError(InputError):
    """A configuration file is unreadable or holds a bad key or value."""

    def __init__(self, path: Path, key: str, value: Any, allowed: str) -> None:
        self.path = path
        self.key = key
        self.value = value
        self.allowed = allowed
        super().__init__(f"{path}: {key} = {value!r}: not allowed (allowed: {allowed})")


@settings
class StationSection(StationInfo):
    """[station]: the station's geometry and constants (station.session.StationInfo) and its counter's time base."""

    timer_tick_s: float = spec(in_range(0.0, 1e-3, lo_open=True), default=constants.TIMER_TICK_S)


@settings
class LimitsSection:
    freq_min_hz: float = spec(in_range(0.0, 100.0, lo_open=True))
    freq_max_hz: float = spec(in_range(0.0, 100.0, lo_open=True))
    displacement_max_m: float = spec(in_range(0.0, 0.1, lo_open=True))
    accel_min_g: float = spec(in_range(0.0, 100.0))
    accel_max_g: float = spec(in_range(0.0, 100.0, lo_open=True))
    payload_max_kg: float = spec(in_range(0.0, 1000.0, lo_open=True))
    payload_size_mm: tuple[float, float, float] = spec(in_range(0.0, 2000.0, lo_open=True))
    ramp_max_hz_per_s: float = spec(in_range(0.0, 100.0, lo_open=True))


@settings
class ServoSection:
    interface: str = spec((bool, "a python-can interface name, e.g. socketcan or virtual"))
    channel: str = spec((bool, "a non-empty channel name, e.g. can0"))
    node_id: int = spec(in_range(1, 127))
    eds: Path = Field(strict=False, json_schema_extra={"allowed": "a file, relative to the station file"})
    heartbeat_ms: int = spec(in_range(10, 10_000))
    timeout_s: float = spec(in_range(0.0, 10.0, lo_open=True))
    # every enabled TPDO's, set at connect (0x1800+n sub 5); the driver's state and ramp waits allow 0.5 s for
    # the TPDO that confirms them (STATE_TIMEOUT_S, RAMP_MARGIN_S), hence the bound
    tpdo_event_timer_ms: int = spec(in_range(1, 500))


@settings
class SerialSection:
    port: str | None = spec((bool, "a device path such as /dev/ttyUSB0"), optional=True)
    baud: int = spec(in_range(300, 4_000_000))


@settings
class IndexingHeadSection(SerialSection):
    speed_deg_s: float = spec(in_range(0.0, 360.0, lo_open=True))
    settle_tol_deg: float = spec(in_range(0.0, 1.0, lo_open=True))
    settle_time_s: float = spec(in_range(0.0, 60.0))


@settings
class PayloadSection:
    mass_kg: float = spec(in_range(0.0, 1000.0))
    size_mm: tuple[float, float, float] = spec(in_range(0.0, 2000.0, lo_open=True))


@dataclass(frozen=True)
class StationConfig:
    path: Path
    simulated: bool
    station: StationSection
    limits: LimitsSection
    servo: ServoSection | None  # the vibration table's four (TABLE_SECTIONS): all present or all None
    grating: SerialSection | None
    reference: SerialSection | None
    counter: SerialSection | None
    indexing_head: IndexingHeadSection
    payload: PayloadSection
    extras: dict[str, Any] = field(default_factory=dict)  # sections of further devices (drivers.registry)
    station_id: str = ""  # top-level `station_id`: which station made a session (provenance); default: the file's stem

    def with_serial_ports(self, **ports: str) -> StationConfig:
        """A copy with serial ports filled in (e.g. emulator pty paths), by section name."""
        changes: dict[str, Any] = {}
        extras = dict(self.extras)
        for name, port in ports.items():
            if name in SERIAL_SECTIONS and getattr(self, name) is not None:
                changes[name] = dataclasses.replace(getattr(self, name), port=port)
            elif name in extras:
                extras[name] = dataclasses.replace(extras[name], port=port)
            else:
                present = [n for n in SERIAL_SECTIONS if getattr(self, n) is not None]
                raise ConfigError(self.path, name, port, f"one of {', '.join((*present, *extras))}")
        return dataclasses.replace(self, **changes, extras=extras)

    def core_devices(self) -> tuple[str, ...]:
        """The vibration table's devices and the indexing head that this station has, in the order they open."""
        return tuple(name for name in _core_kinds() if getattr(self, name) is not None)

    def station_model(self) -> StationModel:
        """What planning knows of this station: its geometry, limits, motion speeds and devices."""
        s, lim, h = self.station, self.limits, self.indexing_head
        return StationModel(
            devices=frozenset(self.core_devices()) | frozenset(self.extras),
            sections=dict(self.extras),
            station=StationInfo(s.A0_m, s.latitude_deg, s.g_mps2, s.earth_rate_radps, s.pulses_per_rev),
            freq_min_hz=lim.freq_min_hz,
            freq_max_hz=lim.freq_max_hz,
            accel_min_g=lim.accel_min_g,
            accel_max_g=lim.accel_max_g,
            ramp_hz_per_s=lim.ramp_max_hz_per_s,
            index_speed_deg_s=h.speed_deg_s,
            index_settle_s=h.settle_time_s,
        )


def _core_kinds() -> dict[str, type]:
    """The sections of the vibration table's devices and the indexing head (drivers.registry kinds with
    core=True), the drive first, the serial devices after it: the order they open."""
    kinds = {name: kind.section for name, kind in device_kinds().items() if kind.core}
    return {name: kinds[name] for name in (*TABLE_SECTIONS, *(n for n in kinds if n not in TABLE_SECTIONS))}


def _required_sections() -> dict[str, type]:
    """Every section a station file may have besides further devices, by name: the station's own, the vibration
    table's (TABLE_SECTIONS, all or none) and the indexing head's."""
    return {"station": StationSection, "limits": LimitsSection, **_core_kinds(), "payload": PayloadSection}


def _section(path: Path, name: str, table: Any, simulated: bool, cls: type) -> Any:
    """One section of a station file, every declared key required (ports optional when simulated), validated
    by its declaration (pydantic; station.validation) and refused with the file, key, value and what is allowed."""
    if not isinstance(table, dict):
        raise ConfigError(path, f"[{name}]", table, "a table")
    fields = settings_fields(cls)
    for key in table:
        if key not in fields:
            raise ConfigError(path, f"[{name}] {key}", table[key], f"keys {', '.join(fields)}")
    values: dict[str, Any] = {}
    for fname, info in fields.items():
        if fname not in table:
            if field_optional(info) and simulated:
                values[fname] = None
                continue
            why = " (optional only when simulated = true)" if field_optional(info) else ""
            raise ConfigError(path, f"[{name}] {fname}", None, f"a required key{why}")
        value = table[fname]
        values[fname] = tuple(value) if isinstance(value, list) else value  # TOML has arrays, sections tuples
    if name == "servo" and isinstance(values["eds"], str):
        eds = (path.parent / values["eds"]).resolve()
        if not eds.is_file():
            allowed = "an existing file, relative to the config file's directory"
            raise ConfigError(path, "[servo] eds", values["eds"], allowed)
        values["eds"] = eds
    try:
        return cls(**values)
    except ValidationError as exc:
        d = next(defects(exc, fields))
        fname = d.field.split("[")[0]
        allowed = d.allowed
        if isinstance(values.get(fname), tuple):
            allowed = f"a list of {len(_tuple_items(fields[fname]))} numbers, each {field_allowed(fields[fname])}"
        raise ConfigError(path, f"[{name}] {fname}", table[fname], allowed) from None


def _tuple_items(info: FieldInfo) -> tuple[Any, ...]:
    return get_args(info.annotation)


def _cross_check(cfg: StationConfig) -> None:
    """Relations between keys: ranges ordered, payload within limits, sim on a virtual bus."""
    lim, p = cfg.limits, cfg.path
    if lim.freq_min_hz >= lim.freq_max_hz:
        raise ConfigError(p, "[limits] freq_min_hz", lim.freq_min_hz, f"< {lim.freq_max_hz:g}")
    if lim.accel_min_g >= lim.accel_max_g:
        raise ConfigError(p, "[limits] accel_min_g", lim.accel_min_g, f"< {lim.accel_max_g:g}")
    if cfg.station.A0_m > lim.displacement_max_m:
        allowed = f"<= [limits] displacement_max_m = {lim.displacement_max_m:g}"
        raise ConfigError(p, "[station] A0_m", cfg.station.A0_m, allowed)
    if cfg.payload.mass_kg > lim.payload_max_kg:
        allowed = f"<= [limits] payload_max_kg = {lim.payload_max_kg:g}"
        raise ConfigError(p, "[payload] mass_kg", cfg.payload.mass_kg, allowed)
    if any(s > m for s, m in zip(cfg.payload.size_mm, lim.payload_size_mm, strict=True)):
        allowed = f"each <= [limits] payload_size_mm = {list(lim.payload_size_mm)}"
        raise ConfigError(p, "[payload] size_mm", list(cfg.payload.size_mm), allowed)
    if cfg.simulated and cfg.servo is not None and cfg.servo.interface != "virtual":
        allowed = "'virtual' when simulated = true"
        raise ConfigError(p, "[servo] interface", cfg.servo.interface, allowed)


def load_station_config(path: str | Path) -> StationConfig:
    """Read and validate a station TOML file."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            doc = tomllib.load(f)
    except OSError as e:
        raise ConfigError(path, "<file>", str(path), f"a readable file ({e.strerror})") from e
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(path, "<syntax>", str(e), "valid TOML") from e
    simulated = doc.pop("simulated", False)
    if not isinstance(simulated, bool):
        raise ConfigError(path, "simulated", simulated, "true or false")
    station_id = doc.pop("station_id", path.stem)
    if not isinstance(station_id, str) or not station_id.strip():
        raise ConfigError(path, "station_id", station_id, 'a non-empty name of the station, e.g. "lab2-table1"')
    required = _required_sections()
    kinds = {name: kind for name, kind in device_kinds().items() if name not in required}
    for key in doc:
        if key not in required and key not in kinds:
            allowed = f"sections {', '.join(required)}, optional devices {', '.join(kinds) or 'none'}, and simulated"
            raise ConfigError(path, key, doc[key], allowed)
    table = [name for name in TABLE_SECTIONS if name in doc]
    for name in required:
        if name not in doc and (name not in TABLE_SECTIONS or table):
            why = f" (the vibration table's sections come together: {', '.join(TABLE_SECTIONS)})" if table else ""
            raise ConfigError(path, f"[{name}]", None, f"a required section{why}")
    sections: dict[str, Any] = {
        name: _section(path, name, doc[name], simulated, cls) if name in doc else None for name, cls in required.items()
    }
    extras = {name: _section(path, name, doc[name], simulated, kinds[name].section) for name in doc if name in kinds}
    cfg = StationConfig(path=path, simulated=simulated, **sections, extras=extras, station_id=station_id.strip())
    _cross_check(cfg)
    return cfg
