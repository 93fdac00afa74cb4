"""Typed measurement records: each method declares its record types once (fields, units, dtypes, ranges).

A `RecordType` is the one declaration of a kind of `Measurement` (station/session.py): the dry run checks the
nominal records against it, the store keeps it with every session that holds such records and coerces values
through it, the export writes it into session.json (piga-session/1, docs/interchange.md) and the import checks
every cell against it. Values are scalars or (nested) lists of one dtype; `arrays` are named numpy arrays.

    TILT = declare("tilt", [Field("freq_hz", "float64", "Hz", lo=0, hi=100)],
                   arrays=[Field("t_s", "float64", "s")])
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from station.errors import InputError

DType = Literal["float64", "int64", "bool", "str"]
DTYPES: tuple[str, ...] = ("float64", "int64", "bool", "str")
INT64_MAX = 2**63 - 1
MAX_NDIM = 8  # list depth of a declared value, dimensions of a declared array


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_real(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


class RecordError(InputError):
    """A value that does not fit its declared field: names the record, field, value and what is allowed."""

    def __init__(self, where: str, name: str, value: Any, allowed: str) -> None:
        self.where, self.name, self.value, self.allowed = where, name, value, allowed
        super().__init__(f"{where}: field {name!r} = {value!r}: not allowed (allowed: {allowed})")


@dataclass(frozen=True)
class Field:
    """One declared value of a record: dtype, unit ('' = dimensionless), closed range, list depth, nullable."""

    name: str
    dtype: DType
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    ndim: int = 0  # 0: a scalar; 1: a list; 2: a list of lists (a matrix) ...
    lo_open: bool = False  # lo itself not allowed
    nullable: bool = False
    doc: str = ""

    def __post_init__(self) -> None:
        """Every key of the declaration in its type (a declaration may come from a file: session.json)."""
        where = f"field {self.name!r}"
        if not isinstance(self.name, str) or not self.name:
            raise RecordError("field", "name", self.name, "non-empty text")
        if self.dtype not in DTYPES:
            raise RecordError(where, "dtype", self.dtype, " | ".join(DTYPES))
        if not _is_int(self.ndim) or not 0 <= self.ndim <= MAX_NDIM:
            raise RecordError(where, "ndim", self.ndim, f"a whole number in [0, {MAX_NDIM}]")
        for key in ("unit", "doc"):
            if not isinstance(getattr(self, key), str):
                raise RecordError(where, key, getattr(self, key), "text")
        for key in ("lo_open", "nullable"):
            if not isinstance(getattr(self, key), bool):
                raise RecordError(where, key, getattr(self, key), "true or false")
        for key in ("lo", "hi"):
            bound = getattr(self, key)
            if bound is not None and not (_is_real(bound) and math.isfinite(bound)):
                raise RecordError(where, key, bound, "a finite number or null")
        if self.lo is not None and self.hi is not None and not self.lo <= self.hi:
            raise RecordError(where, "hi", self.hi, f"a number >= lo = {self.lo:g}")
        if (self.lo is not None or self.hi is not None) and self.dtype in ("bool", "str"):
            raise RecordError(where, "lo/hi", (self.lo, self.hi), f"null for dtype {self.dtype} (a range is numeric)")

    def allowed(self) -> str:
        what = {"float64": "a finite number", "int64": "a whole number", "bool": "true or false", "str": "text"}
        text = what[self.dtype]
        if self.lo is not None or self.hi is not None:
            lo = "(-inf" if self.lo is None else f"{'(' if self.lo_open else '['}{self.lo:g}"
            text += f" in {lo}, {'inf)' if self.hi is None else f'{self.hi:g}]'}"
        if self.unit:
            text += f" ({self.unit})"
        if self.ndim:
            text = f"a {self.ndim}-deep list of {text}"
        return text + (" or null" if self.nullable else "")

    def coerce(self, value: Any, where: str) -> Any:
        """The value in its declared type (ints as int, floats as float), or RecordError."""
        if value is None:
            if self.nullable:
                return None
            raise RecordError(where, self.name, value, self.allowed())
        return self._coerce(value, self.ndim, where, value)

    def _coerce(self, value: Any, depth: int, where: str, whole: Any) -> Any:
        if depth:
            if isinstance(value, np.ndarray):
                value = value.tolist()
            if not isinstance(value, list | tuple):
                raise RecordError(where, self.name, whole, self.allowed())
            return [self._coerce(v, depth - 1, where, whole) for v in value]
        return self._scalar(value, where, whole)

    def _scalar(self, value: Any, where: str, whole: Any) -> Any:
        if isinstance(value, np.generic):
            value = value.item()
        if self.dtype == "str":
            if not isinstance(value, str):
                raise RecordError(where, self.name, whole, self.allowed())
            return value
        if self.dtype == "bool":
            if not isinstance(value, bool):
                raise RecordError(where, self.name, whole, self.allowed())
            return value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise RecordError(where, self.name, whole, self.allowed())
        if self.dtype == "int64":
            if isinstance(value, float) and not value.is_integer():
                raise RecordError(where, self.name, whole, self.allowed())
            value = int(value)
            if abs(value) > INT64_MAX:
                raise RecordError(where, self.name, whole, self.allowed())
        else:
            value = float(value)
            if not math.isfinite(value):
                raise RecordError(where, self.name, whole, self.allowed())
        if not self.in_range(value):
            raise RecordError(where, self.name, whole, self.allowed())
        return value

    def in_range(self, value: float) -> bool:
        if self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo):
            return False
        return self.hi is None or value <= self.hi

    def to_json(self) -> dict:
        """The declaration as JSON, keys left out where they hold their default."""
        defaults = {f.name: f.default for f in dataclasses.fields(self)}

        def kept(k: str, v: Any) -> bool:
            d = defaults[k]
            return k in ("name", "dtype") or (v is not None if d is None else v != d)

        return {k: v for k, v in asdict(self).items() if kept(k, v)}

    @classmethod
    def from_json(cls, doc: Mapping[str, Any], where: str) -> Field:
        allowed = {f for f in cls.__dataclass_fields__}
        if not isinstance(doc, Mapping) or not isinstance(doc.get("name"), str) or "dtype" not in doc:
            raise RecordError(where, "field", doc, "an object with at least 'name' and 'dtype'")
        unknown = sorted(set(doc) - allowed)
        if unknown:
            raise RecordError(where, doc["name"], unknown, "keys " + ", ".join(sorted(allowed)))
        return cls(**dict(doc))


@dataclass(frozen=True)
class RecordType:
    """The declaration of one kind of measurement record: its values and its arrays."""

    kind: str
    fields: tuple[Field, ...]
    arrays: tuple[Field, ...] = ()
    doc: str = ""
    _by_name: dict[str, Field] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        for group in (self.fields, self.arrays):
            names = [f.name for f in group]
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise RecordError(f"record type {self.kind!r}", "fields", dup, "each name once")
        self._by_name.update({f.name: f for f in self.fields})

    def field(self, name: str) -> Field:
        return self._by_name[name]

    def check_values(self, values: Mapping[str, Any], where: str) -> dict[str, Any]:
        """Every declared field present (a nullable one may be missing: it becomes null), no undeclared one; typed
        copies, every declared field in declaration order (a record is a row of its kind's table)."""
        where = f"{where} ({self.kind})"
        unknown = sorted(set(values) - set(self._by_name))
        if unknown:
            raise RecordError(where, unknown[0], values[unknown[0]], "one of " + ", ".join(self._by_name))
        out = {}
        for f in self.fields:
            if f.name not in values and not f.nullable:
                raise RecordError(where, f.name, "<missing>", f.allowed())
            out[f.name] = f.coerce(values.get(f.name), where)
        return out

    def check_arrays(self, arrays: Mapping[str, np.ndarray], where: str) -> dict[str, np.ndarray]:
        """Declared arrays only, each of its dtype (1-D unless declared deeper), finite, within range."""
        where = f"{where} ({self.kind})"
        declared = {a.name: a for a in self.arrays}
        out = {}
        for name, value in arrays.items():
            if name not in declared:
                raise RecordError(where, name, "<array>", "arrays " + (", ".join(declared) or "none"))
            out[name] = check_array(declared[name], np.asarray(value), where)
        return out

    def to_json(self) -> dict:
        doc = {"kind": self.kind, "fields": [f.to_json() for f in self.fields]}
        if self.arrays:
            doc["arrays"] = [a.to_json() for a in self.arrays]
        if self.doc:
            doc["doc"] = self.doc
        return doc

    @classmethod
    def from_json(cls, doc: Any, where: str) -> RecordType:
        if not isinstance(doc, Mapping) or not isinstance(doc.get("kind"), str):
            raise RecordError(where, "record type", doc, "an object with 'kind', 'fields' and optional 'arrays'")
        kind = doc["kind"]
        if not isinstance(doc.get("doc", ""), str):
            raise RecordError(f"{where} {kind}", "doc", doc["doc"], "text")
        groups = []
        for key in ("fields", "arrays"):
            items = doc.get(key, [])
            if not isinstance(items, list):
                raise RecordError(f"{where} {kind}", key, items, "a list of field declarations")
            groups.append(tuple(Field.from_json(f, f"{where} {kind}.{key}") for f in items))
        return cls(kind, groups[0], groups[1], doc.get("doc", ""))


def check_array(f: Field, a: np.ndarray, where: str) -> np.ndarray:
    """An array in its declared dtype: numeric, finite and within [lo, hi]."""
    ndim = max(f.ndim, 1)
    if a.ndim != ndim:
        raise RecordError(where, f.name, f"shape {a.shape}", f"a {ndim}-D array")
    if f.dtype in ("float64", "int64"):
        if a.dtype.kind not in "biuf":  # no complex (astype would drop the imaginary part), object or text
            raise RecordError(where, f.name, f"dtype {a.dtype}", f.allowed())
        if f.dtype == "int64" and a.size and not np.issubdtype(a.dtype, np.integer):
            raise RecordError(where, f.name, f"dtype {a.dtype}", f.allowed())
        a = a.astype(f.dtype, copy=False)
        if f.dtype == "float64" and not np.all(np.isfinite(a)):
            raise RecordError(where, f.name, f"{int(np.sum(~np.isfinite(a)))} NaN or inf", f.allowed())
        if a.size and not (f.in_range(a.min()) and f.in_range(a.max())):
            raise RecordError(where, f.name, f"range [{a.min():g}, {a.max():g}]", f.allowed())
        return a
    if f.dtype == "bool" and a.dtype != bool:
        raise RecordError(where, f.name, f"dtype {a.dtype}", f.allowed())
    return a


_DECLARED: dict[str, RecordType] = {}


def declare(kind: str, fields: Iterable[Field], *, arrays: Iterable[Field] = (), doc: str = "") -> RecordType:
    """Declare a record type once (at import of the method that records it); the same declaration again is a no-op."""
    rt = RecordType(kind, tuple(fields), tuple(arrays), doc)
    old = _DECLARED.get(kind)
    if old is not None and old.to_json() != rt.to_json():
        raise RecordError(
            f"record type {kind!r}", "kind", kind, "one declaration per kind (declared twice, differently)"
        )
    _DECLARED[kind] = rt
    return rt


def declared(kind: str) -> RecordType | None:
    """The record type declared for `kind` in this process, if any."""
    return _DECLARED.get(kind)


def declared_types() -> dict[str, RecordType]:
    return dict(_DECLARED)


def infer_record_type(kind: str, values: Mapping[str, Any], arrays: Mapping[str, Any] | None = None) -> RecordType:
    """A declaration read off one record (for sessions stored before records were declared; units unknown)."""

    def dtype_of(v: Any) -> tuple[str, int]:
        depth = 0
        while isinstance(v, list | tuple):
            depth += 1
            v = v[0] if v else 0.0
        if isinstance(v, bool):
            return "bool", depth
        if isinstance(v, int):
            return "int64", depth
        if isinstance(v, float):
            return "float64", depth
        return "str", depth

    fields = []
    for name, v in values.items():
        dt, nd = dtype_of(v)
        fields.append(Field(name, dt, ndim=nd, nullable=v is None))  # type: ignore[arg-type]
    arr = []
    for name, a in dict(arrays or {}).items():
        a = np.asarray(a)
        dt = (
            "float64"
            if np.issubdtype(a.dtype, np.floating)
            else "int64"
            if np.issubdtype(a.dtype, np.integer)
            else "bool"
        )
        arr.append(Field(name, dt, ndim=a.ndim))  # type: ignore[arg-type]
    return RecordType(kind, tuple(fields), tuple(arr), "inferred from a stored record: units unknown")


def field_names(fields: Sequence[Field]) -> list[str]:
    return [f.name for f in fields]
