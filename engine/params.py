"""Declared procedure parameters and their validation (from TOML procedure files or the panel).

A procedure declares its parameters as `Param`s; `validate_params` turns raw
values into typed ones and refuses anything else with the parameter's name,
the value and what is allowed, before anything moves.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from station.errors import InputError


class ParameterError(InputError):
    """A procedure parameter that is missing, unknown, of the wrong type or out of range."""


@dataclass(frozen=True)
class Param:
    name: str
    kind: type  # float, int, str, bool, or list (of float)
    default: Any = None
    min: float | None = None
    max: float | None = None
    choices: Sequence[str] | None = None
    unit: str = ""
    help: str = ""
    required: bool = False

    def allowed(self) -> str:
        if self.choices:
            return "one of " + ", ".join(map(repr, self.choices))
        kind = "list of numbers" if self.kind is list else self.kind.__name__
        lo = "-inf" if self.min is None else f"{self.min:g}"
        hi = "inf" if self.max is None else f"{self.max:g}"
        rng = f" in [{lo}, {hi}]" if self.min is not None or self.max is not None else ""
        return f"{kind}{rng}{(' ' + self.unit) if self.unit else ''}"

    def describe(self) -> dict:
        """The declaration as JSON, for a form that validates before it submits."""
        kind = {float: "float", int: "int", str: "str", bool: "bool", list: "list"}[self.kind]
        return {"name": self.name, "kind": kind, "default": self.default, "min": self.min, "max": self.max,
                "choices": list(self.choices) if self.choices else None, "unit": self.unit, "help": self.help,
                "required": self.required, "allowed": self.allowed()}  # fmt: skip

    def _number(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ParameterError(f"{where} = {value!r}: expected {self.allowed()}")
        if (self.min is not None and value < self.min) or (self.max is not None and value > self.max):
            raise ParameterError(f"{where} = {value!r}: out of range, allowed {self.allowed()}")
        return value

    def coerce(self, value: Any, procedure: str) -> Any:
        where = f"procedure {procedure!r} parameter {self.name!r}"
        if self.kind is list:
            if isinstance(value, str) or not isinstance(value, Sequence) or not value:
                raise ParameterError(f"{where} = {value!r}: expected a non-empty {self.allowed()}")
            return [float(self._number(v, f"{where}[{i}]")) for i, v in enumerate(value)]
        if self.kind is bool:
            if not isinstance(value, bool):
                raise ParameterError(f"{where} = {value!r}: expected true or false")
            return value
        if self.kind is str:
            if not isinstance(value, str) or (self.choices and value not in self.choices):
                raise ParameterError(f"{where} = {value!r}: expected {self.allowed()}")
            return value
        if self.kind is int:
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            if not isinstance(value, int) or isinstance(value, bool):
                raise ParameterError(f"{where} = {value!r}: expected a whole number, {self.allowed()}")
        return self.kind(self._number(value, where))


def validate_params(procedure: str, declared: Sequence[Param], given: Mapping[str, Any]) -> dict[str, Any]:
    """Typed parameters with defaults filled in; ParameterError on the first defect."""
    known = {p.name: p for p in declared}
    unknown = sorted(set(given) - set(known))
    if unknown:
        raise ParameterError(
            f"procedure {procedure!r}: unknown parameter(s) {', '.join(map(repr, unknown))}; "
            f"allowed: {', '.join(known) or 'none'}"
        )
    out: dict[str, Any] = {}
    for p in declared:
        if p.name in given:
            out[p.name] = p.coerce(given[p.name], procedure)
        elif p.required:
            raise ParameterError(f"procedure {procedure!r}: missing parameter {p.name!r} ({p.allowed()})")
        else:
            out[p.name] = p.default
    return out
