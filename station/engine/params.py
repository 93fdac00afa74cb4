"""Declared procedure parameters and their validation (from TOML procedure files or the panel).

A procedure declares its parameters as `Param`s; `validate_params` turns raw
values into typed ones and refuses anything else with the parameter's name,
the value and what is allowed, before anything moves.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, Field, ValidationError, create_model

from station.errors import InputError
from station.validation import SETTINGS, Defect, defects


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

    def label(self) -> str:
        """The parameter in words, for a form, from its help as written (u(z0) is not U(z0)): without its asides in
        parentheses, up to the first ';' and the first ':' (unless one or two words follow it, which name the part:
        'measured Zs1(w): z1'); its name in words where the help says too little; with its unit (none for a pure
        number, unit '1')."""
        words = re.split(r";", re.sub(r"\s+\([^()]*\)", "", self.help), maxsplit=1)[0].strip()
        head, colon, tail = words.partition(":")
        words = head.strip() if colon and len(tail.split()) > 2 else words
        if len(words) < 4:
            tokens = self.name.split("_")
            words = " ".join(tokens[:-1] if self.unit and len(tokens) > 1 else tokens)
        unit = f" ({self.unit})" if self.unit not in ("", "1") else ""
        return words + unit

    def describe(self) -> dict:
        """The declaration as JSON, for a form that validates before it submits."""
        kind = {float: "float", int: "int", str: "str", bool: "bool", list: "list"}[self.kind]
        return {"name": self.name, "label": self.label(), "kind": kind, "default": self.default, "min": self.min,
                "max": self.max,
                "choices": list(self.choices) if self.choices else None, "unit": self.unit, "help": self.help,
                "required": self.required, "allowed": self.allowed()}  # fmt: skip

    def annotation(self) -> Any:
        """The parameter's type with its bounds, as pydantic validates it."""
        bounds = Field(ge=self.min, le=self.max)
        if self.kind is list:
            return Annotated[list[Annotated[float, bounds]], Field(min_length=1)]
        if self.kind is str:
            return Literal[tuple(self.choices)] if self.choices else str
        if self.kind is int:
            return Annotated[int, BeforeValidator(_whole), bounds]
        if self.kind is float:
            return Annotated[float, bounds]
        return self.kind

    def message(self, procedure: str, defect: Defect) -> str:
        """The defect in the words of a procedure file: parameter, value, what is allowed."""
        where = f"procedure {procedure!r} parameter {self.name!r}{defect.field[len(self.name) :]}"
        if defect.kind == "missing":
            return f"procedure {procedure!r}: missing parameter {self.name!r} ({self.allowed()})"
        if defect.kind in ("greater_than_equal", "less_than_equal"):
            return f"{where} = {defect.value!r}: out of range, allowed {self.allowed()}"
        if self.kind is list and defect.field == self.name:
            return f"{where} = {defect.value!r}: expected a non-empty {self.allowed()}"
        if self.kind is bool:
            return f"{where} = {defect.value!r}: expected true or false"
        if self.kind is int:
            return f"{where} = {defect.value!r}: expected a whole number, {self.allowed()}"
        return f"{where} = {defect.value!r}: expected {self.allowed()}"


def _whole(value: Any) -> Any:
    """A whole number written as a float (TOML 3.0) is the int 3."""
    return int(value) if isinstance(value, float) and value.is_integer() else value


def params_model(procedure: str, declared: Sequence[Param]) -> type[BaseModel]:
    """The pydantic model of a procedure's parameters: the one declaration that the run, the dry run and
    the panel's form (its JSON schema) use."""
    fields: dict[str, Any] = {
        p.name: (
            p.annotation() if p.required or p.default is not None else p.annotation() | None,  # None: not given
            Field(... if p.required else p.default, description=p.help or None),
        )
        for p in declared
    }
    return create_model(f"Params[{procedure}]", __config__=SETTINGS, **fields)


def validate_params(procedure: str, declared: Sequence[Param], given: Mapping[str, Any]) -> dict[str, Any]:
    """Typed parameters with defaults filled in; ParameterError on the first defect (unknown names first)."""
    known = {p.name: p for p in declared}
    unknown = sorted(set(given) - set(known))
    if unknown:
        raise ParameterError(
            f"procedure {procedure!r}: unknown parameter(s) {', '.join(map(repr, unknown))}; "
            f"allowed: {', '.join(known) or 'none'}"
        )
    model = params_model(procedure, declared)
    try:
        return model.model_validate(dict(given)).model_dump()
    except ValidationError as exc:
        order = list(known)
        first = min(defects(exc, model.model_fields), key=lambda d: order.index(d.field.split("[")[0]))
        raise ParameterError(known[first.field.split("[")[0]].message(procedure, first)) from None
