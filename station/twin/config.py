"""Twin configuration: station geometry, instrument coefficients, effects and noise.

Every effect of the table in physics.md is switchable by name with its
parameters (`TwinConfig.with_effect`), as its module in station.twin.effects declares them. Units: metres, seconds,
radians,
rad/s for rates, g for accelerations inside the instrument model.
"""

from __future__ import annotations

import functools
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

from pydantic import BaseModel, ValidationError, create_model

from station import constants
from station.errors import InputError
from station.session import StationInfo
from station.tomlfile import read_toml
from station.twin.effects import EFFECTS, Effect
from station.validation import SETTINGS, defects, in_range, settings, settings_fields, spec

NON_NEGATIVE = in_range(0.0, math.inf)
POSITIVE = in_range(0.0, math.inf, lo_open=True)


class TwinConfigError(InputError):
    """A twin configuration that names an unknown effect, parameter or a bad value."""


@settings
class InstrumentCoefficients:
    """Nominal PIGA rate-model terms (physics.md); seed 000 simulation values by default."""

    k0: float = constants.K0_RADPS
    kz: float = constants.KZ_RADPS_PER_G
    kzz: float = constants.KZZ_RADPS_PER_G2
    ky: float = constants.KY_RADPS_PER_G2
    k3: float = constants.K3_RADPS_PER_G3


@settings
class NoiseModel:
    """Measurement noise of one point.

    rate_noise_radps: standard deviation of the window-mean rate error of a
    window of `rate_noise_ref_s` seconds; white rate noise, so it scales as
    sqrt(rate_noise_ref_s / Tm). timing_jitter_s: Gaussian jitter of every
    time stamp (pulse and reference edges). timer_tick_s: counter/timer
    quantisation (0 turns it off).
    """

    rate_noise_radps: float = spec(NON_NEGATIVE, default=0.0)
    rate_noise_ref_s: float = spec(POSITIVE, default=560.0)
    timing_jitter_s: float = spec(NON_NEGATIVE, default=0.0)
    timer_tick_s: float = spec(NON_NEGATIVE, default=constants.TIMER_TICK_S)
    grating_noise_m: float = spec(NON_NEGATIVE, default=0.0)


@functools.cache
def _effect_model(effect: Effect) -> type[BaseModel]:
    """The declared parameters of one effect, each a finite number with its default."""
    declared: dict[str, Any] = {k: (float, d) for k, d in effect.defaults.items()}
    return create_model(f"Effect[{effect.name}]", __config__=SETTINGS, **declared)


def effect_params(name: str, given: Mapping[str, float] | None = None) -> Mapping[str, float]:
    """Defaults of effect `name` overlaid with `given`, validated."""
    if name not in EFFECTS:
        raise TwinConfigError(f"unknown effect {name!r}; known effects: {', '.join(EFFECTS)}")
    effect = EFFECTS[name]
    try:
        params = _effect_model(effect).model_validate(dict(given or {})).model_dump()
    except ValidationError as exc:
        d = next(defects(exc, _effect_model(effect).model_fields))
        if d.is_unknown:
            allowed = ", ".join(effect.params)
            raise TwinConfigError(f"effect {name!r} has no parameter {d.field!r}; allowed: {allowed}") from None
        where = f"effect {name!r} parameter {d.field!r}"
        raise TwinConfigError(f"{where} = {d.value!r}: expected a finite number") from None
    problem = effect.check(params) if effect.check else ""
    if problem:
        raise TwinConfigError(f"effect {name!r}: {problem}")
    return MappingProxyType(params)


@dataclass(frozen=True)
class TwinConfig:
    """Everything the twin needs: geometry, instrument, effects switched on, noise."""

    station: StationInfo = field(default_factory=StationInfo)
    instrument: InstrumentCoefficients = field(default_factory=InstrumentCoefficients)
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: MappingProxyType({}))
    noise: NoiseModel = field(default_factory=NoiseModel)
    earth_rate_on: bool = True

    def __post_init__(self) -> None:
        checked = {name: effect_params(name, p) for name, p in self.effects.items()}
        object.__setattr__(self, "effects", MappingProxyType(checked))

    def with_effect(self, name: str, **params: float) -> TwinConfig:
        """A copy with effect `name` switched on with `params` (others at their defaults)."""
        return replace(self, effects={**self.effects, name: params})

    def without_effect(self, name: str) -> TwinConfig:
        return replace(self, effects={k: v for k, v in self.effects.items() if k != name})

    def param(self, effect: str, key: str) -> float:
        """Parameter `key` of `effect`, or 0 when the effect is off."""
        p = self.effects.get(effect)
        return p[key] if p is not None else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "station": _asdict(self.station),
            "instrument": _asdict(self.instrument),
            "noise": _asdict(self.noise),
            "earth_rate_on": self.earth_rate_on,
            "effects": {k: dict(v) for k, v in self.effects.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "twin config") -> TwinConfig:
        allowed = {"station", "instrument", "noise", "earth_rate_on", "effects"}
        unknown = set(data) - allowed
        if unknown:
            raise TwinConfigError(f"{source}: unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
        kwargs: dict[str, Any] = {}
        for key, klass in (
            ("station", StationInfo),
            ("instrument", InstrumentCoefficients),
            ("noise", NoiseModel),
        ):
            if key in data:
                kwargs[key] = _build(klass, data[key], f"{source} [{key}]")
        if "earth_rate_on" in data:
            if not isinstance(data["earth_rate_on"], bool):
                raise TwinConfigError(f"{source}: earth_rate_on = {data['earth_rate_on']!r}: expected true or false")
            kwargs["earth_rate_on"] = data["earth_rate_on"]
        if "effects" in data:
            try:
                kwargs["effects"] = {str(k): dict(v) for k, v in data["effects"].items()}
            except (AttributeError, TypeError, ValueError) as exc:
                raise TwinConfigError(f"{source} [effects]: expected tables of numbers") from exc
        try:
            return cls(**kwargs)
        except TwinConfigError as exc:
            raise TwinConfigError(f"{source}: {exc}") from None

    @classmethod
    def from_toml(cls, path: str | Path) -> TwinConfig:
        """A twin file over the embedded default twin: a section or key the file leaves out keeps the default's
        value (a file with one [effects.X] section keeps the default noise; it is not a noise-free twin)."""
        data = read_toml(path, "twin config", TwinConfigError)
        base = default_twin().to_dict()
        merged = {"earth_rate_on": base["earth_rate_on"], **data}
        for section in ("station", "instrument", "noise"):
            given = data.get(section, {})
            merged[section] = {**base[section], **given} if isinstance(given, Mapping) else given
        return cls.from_dict(merged, source=str(path))

    def to_toml(self) -> str:
        lines = [f"earth_rate_on = {'true' if self.earth_rate_on else 'false'}", ""]
        for section in ("station", "instrument", "noise"):
            lines.append(f"[{section}]")
            lines += [f"{k} = {v!r}" for k, v in _asdict(getattr(self, section)).items()]
            lines.append("")
        for name, params in self.effects.items():
            lines.append(f"[effects.{name}]")
            lines += [f"{k} = {v!r}" for k, v in params.items()]
            lines.append("")
        return "\n".join(lines)


def _asdict(obj: Any) -> dict[str, Any]:
    return {f.name: getattr(obj, f.name) for f in fields(obj)}


def _build(klass: type, data: Any, where: str) -> Any:
    """A section of a twin file, validated by its declaration (station.validation)."""
    if not isinstance(data, Mapping):
        raise TwinConfigError(f"{where}: expected a table, got {data!r}")
    names = [f.name for f in fields(klass)]
    try:
        return klass(**data)
    except ValidationError as exc:
        d = next(defects(exc, settings_fields(klass)))
        if d.is_unknown:
            raise TwinConfigError(f"{where}: unknown key {d.field!r}; allowed: {', '.join(names)}") from None
        allowed = "a finite number" if d.is_type else d.allowed
        raise TwinConfigError(f"{where}: {d.field} = {d.value!r}: expected {allowed}") from None


def default_twin() -> TwinConfig:
    """The embedded default station (station/twin/data/default_twin.toml)."""
    from importlib.resources import files

    text = files("station.twin").joinpath("data/default_twin.toml").read_text()
    return TwinConfig.from_dict(tomllib.loads(text), source="embedded default twin")
