"""Declared settings, validated by pydantic, with one error format: where, field, value and what is allowed.

A setting is declared once, as a field of a pydantic dataclass (`@settings`) whose default is
`spec(check)`: the check is a range (`in_range`) or a predicate with its "what is allowed" text.
pydantic checks types (strictly: no string for a number, no bool for a count, no NaN) and the
declared constraints; `defects` turns its ValidationError into (field, value, allowed) triples
that every loader (station files, twin files, procedure parameters, session.json) words the
same way. The JSON schema the panel's forms use comes from the same declaration
(`pydantic.TypeAdapter(cls).json_schema()`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, TypeVar, cast, dataclass_transform

from pydantic import AfterValidator, ConfigDict, Field, ValidationError
from pydantic.dataclasses import dataclass as pydantic_dataclass
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

SETTINGS = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

T = TypeVar("T")


def settings_fields(cls: type) -> dict[str, FieldInfo]:
    """The declared fields of a @settings class, by name."""
    fields: dict[str, FieldInfo] = cls.__pydantic_fields__  # type: ignore[attr-defined]
    return fields


@dataclass(frozen=True)
class Check:
    """What a setting allows: a predicate with its text (and, for a range, its JSON-schema bounds)."""

    predicate: Callable[[Any], bool]
    allowed: str
    bounds: tuple[tuple[str, float], ...] = ()


def in_range(lo: float, hi: float, *, lo_open: bool = False) -> Check:
    """lo <= value <= hi (lo < value with lo_open); each element of a tuple value."""
    op = "<" if lo_open else "<="

    def inside(v: float) -> bool:
        return (lo < v if lo_open else lo <= v) and v <= hi

    return Check(
        inside, f"{lo:g} {op} value <= {hi:g}", (("exclusiveMinimum" if lo_open else "minimum", lo), ("maximum", hi))
    )


def spec(
    check: Check | tuple[Callable[[Any], bool], str] | None = None,
    *,
    optional: bool = False,
    default: Any = PydanticUndefined,
) -> Any:
    """A field of a settings section, with what it allows; required unless it has a default.

    `optional`: the key may be left out where the loader says so (a serial port that a simulated
    station's emulator fills in); it is then None. Each element of a tuple value is checked.
    """
    if isinstance(check, tuple):
        check = Check(check[0], check[1])
    extra: dict[str, Any] = {"allowed": check.allowed if check else "", "optional": optional}
    extra.update(check.bounds if check else ())
    info: FieldInfo = Field(default, json_schema_extra=extra)
    if check is not None:
        predicate, allowed = check.predicate, check.allowed

        def satisfies(value: Any) -> Any:
            items = value if isinstance(value, tuple) else (value,)
            if value is not None and not all(predicate(v) for v in items):
                raise ValueError(allowed)
            return value

        info.metadata.append(AfterValidator(satisfies))
    return info


@dataclass_transform(frozen_default=True, field_specifiers=(Field, spec))
def settings(cls: type[T]) -> type[T]:
    """A frozen, validated section of settings (a pydantic dataclass; unknown keys refused)."""
    return cast("type[T]", pydantic_dataclass(frozen=True, config=SETTINGS)(cls))


def field_allowed(info: FieldInfo) -> str:
    """The declared "what is allowed" text of a field."""
    extra = info.json_schema_extra
    return str(extra.get("allowed", "")) if isinstance(extra, dict) else ""


def field_optional(info: FieldInfo) -> bool:
    extra = info.json_schema_extra
    return bool(extra.get("optional", False)) if isinstance(extra, dict) else False


UNKNOWN_KEY = ("extra_forbidden", "unexpected_keyword_argument")
TYPE_NAMES = {"float_type": "float", "int_type": "int", "bool_type": "bool", "string_type": "str",
              "int_from_float": "int", "tuple_type": "tuple", "list_type": "list"}  # fmt: skip


@dataclass(frozen=True)
class Defect:
    """One thing wrong with a declared setting."""

    field: str  # dotted path, list items as [i]
    value: Any
    kind: str  # pydantic's error type: missing, extra_forbidden, float_type, less_than_equal, value_error, ...
    allowed: str

    @property
    def is_unknown(self) -> bool:
        return self.kind in UNKNOWN_KEY

    @property
    def is_type(self) -> bool:
        return self.kind in TYPE_NAMES or self.kind.endswith("_type") or self.kind == "finite_number"


def field_path(loc: tuple[int | str, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def defects(exc: ValidationError, fields: dict[str, FieldInfo]) -> Iterator[Defect]:
    """The defects of a ValidationError, each with what its field allows (the declared text first)."""
    for err in exc.errors():
        loc = tuple(err["loc"])
        name = str(loc[0]) if loc else ""
        info = fields.get(name)
        declared = field_allowed(info) if info is not None else ""
        kind = err["type"]
        if kind in ("float_type", "int_type", "bool_type", "string_type", "finite_number", "int_from_float"):
            allowed = f"a value of type {TYPE_NAMES.get(kind, 'float')}"
        elif kind == "missing":
            allowed = "a required key"
        elif kind in UNKNOWN_KEY:
            allowed = f"keys {', '.join(fields)}"
        else:
            allowed = declared or err["msg"]
        value = None if kind == "missing" else err.get("input")
        yield Defect(field_path(loc), value, kind, allowed)
