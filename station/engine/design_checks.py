"""Checks of a design before anything moves: each problem with its field, value, reason and fix.

A refusal stops the run before the station opens; a warning needs the operator's
consent (`--yes` on the console, Confirm on the panel). The checks are pure
functions of the declared parameters, their values and the plan's time
estimates; a procedure adds its own (`ProcedureSpec.check_design`, e.g. a design
singular for the method's coefficients).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from station.engine.context import ValidationError
from station.engine.params import Param

LONG_PLAN_S = 24 * 3600.0  # a day of station time: longer plans are a mistake more often than a wish
COSTLY_SHARE = 0.5  # the points named for a long plan: the costliest ones that together take half of it
COSTLY_SHOWN = 8  # at most this many named, the rest counted
ANGLE_TOL_DEG = 1e-6  # positions closer than this modulo 360 deg are one orientation of the head (its resolution is
# about 0.1 arcsec = 3e-5 deg, so nothing distinguishes them)
SHOWN_VALUES = 8  # a long list is shown by its first values and its length


@dataclass(frozen=True)
class Finding:
    """One problem of a design: a refusal (the run cannot work) or a warning (it may not be what was meant)."""

    refusal: bool
    field: str
    value: Any
    reason: str
    fix: str

    def line(self) -> str:
        kind = "refused" if self.refusal else "warning"
        return f"{kind}: {self.field} = {_shown(self.value)}: {self.reason}; fix: {self.fix}"

    def to_json(self) -> dict:
        return {"refusal": self.refusal, "field": self.field, "value": self.value, "reason": self.reason,
                "fix": self.fix, "line": self.line()}  # fmt: skip


MethodCheck = Callable[[dict[str, Any]], list[Finding]]


class RefusedDesignError(ValidationError):
    """A design that cannot work: refused before anything moves, one line per problem."""

    def __init__(self, procedure: str, findings: Sequence[Finding]) -> None:
        self.findings = list(findings)
        lines = "\n".join(f"  {f.line()}" for f in self.findings)
        super().__init__(f"procedure {procedure!r}: the design is refused before anything moves:\n{lines}")


def _shown(value: Any) -> str:
    if isinstance(value, list) and len(value) > SHOWN_VALUES:
        head = ", ".join(f"{v:g}" for v in value[:SHOWN_VALUES])
        return f"[{head}, ...] ({len(value)} values)"
    if isinstance(value, list):
        return "[" + ", ".join(f"{v:g}" for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else repr(value)


def bounds_order(declared: Sequence[Param], params: dict[str, Any]) -> list[Finding]:
    """A pair of declared parameters named ..._min... and ..._max... (n_min, n_max) given with min > max."""
    names = {p.name for p in declared}
    out = []
    for p in declared:
        words = p.name.split("_")
        if "min" not in words:
            continue
        partner = "_".join("max" if w == "min" else w for w in words)
        lo, hi = params.get(p.name), params.get(partner)
        if partner in names and lo is not None and hi is not None and lo > hi:
            out.append(Finding(True, p.name, lo, f"bounds in the wrong order: {p.name} = {lo:g} > {partner} = {hi:g}",
                               f"{p.name} <= {partner}, e.g. {p.name} = {hi:g} and {partner} = {lo:g}"))  # fmt: skip
    return out


def _angle_lists(declared: Sequence[Param], params: dict[str, Any]) -> list[tuple[str, list[float]]]:
    return [(p.name, params[p.name]) for p in declared if p.kind is list and p.unit == "deg" and params.get(p.name)]


def radians_looking(declared: Sequence[Param], params: dict[str, Any]) -> list[Finding]:
    """An angle list in degrees whose values all lie within +-2 pi, more than one of them non-zero: radians."""
    out = []
    for name, values in _angle_lists(declared, params):
        nonzero = [v for v in values if v != 0.0]
        if len(nonzero) > 1 and all(abs(v) <= 2 * math.pi for v in values):
            degrees = ", ".join(f"{math.degrees(v):.6g}" for v in values[:SHOWN_VALUES])
            more = ", ..." if len(values) > SHOWN_VALUES else ""
            out.append(Finding(False, name, values, "every value is within +-2 pi = 6.283: these look like radians",
                               f"give degrees, e.g. [{degrees}{more}]"))  # fmt: skip
    return out


def equal_modulo_360(declared: Sequence[Param], params: dict[str, Any]) -> list[Finding]:
    """Angles of a list that are one orientation of the head (equal modulo 360 deg)."""
    out = []
    for name, values in _angle_lists(declared, params):
        groups: dict[float, list[float]] = {}
        for v in values:
            key = round(v % 360.0 / ANGLE_TOL_DEG) * ANGLE_TOL_DEG % 360.0
            groups.setdefault(key, []).append(v)
        same = [g for g in groups.values() if len(g) > 1]
        if same:
            which = "; ".join(", ".join(f"{v:g}" for v in g) for g in same[:SHOWN_VALUES])
            out.append(Finding(False, name, values, f"{which} deg are one orientation (equal modulo 360 deg)",
                               "keep one angle of each orientation and choose distinct ones for the rest"))  # fmt: skip
    return out


def check_params(
    declared: Sequence[Param], params: dict[str, Any], method_check: MethodCheck | None = None
) -> list[Finding]:
    """Every problem of the parameters alone. Equal angles become a refusal where the method's check refuses
    the same field (they make its design singular); otherwise they are a warning."""
    method = method_check(params) if method_check is not None else []
    refused = {f.field for f in method if f.refusal}
    same = [replace(f, refusal=True) if f.field in refused else f for f in equal_modulo_360(declared, params)]
    return [*bounds_order(declared, params), *radians_looking(declared, params), *same, *method]


def long_plan(estimates_s: dict[str, float]) -> list[Finding]:
    """A plan over LONG_PLAN_S of station time, naming the points that cost it (the costliest ones that together
    take COSTLY_SHARE of it)."""
    total_s = sum(estimates_s.values())
    if total_s <= LONG_PLAN_S:
        return []
    ranked = sorted(estimates_s.items(), key=lambda kv: -kv[1])
    costly, acc_s = [], 0.0
    for k, s in ranked:
        if acc_s >= COSTLY_SHARE * total_s:
            break
        costly.append((k, s))
        acc_s += s
    named = ", ".join(f"{k} {s / 3600:.1f} h" for k, s in costly[:COSTLY_SHOWN])
    more = f" and {len(costly) - COSTLY_SHOWN} more" if len(costly) > COSTLY_SHOWN else ""
    share = acc_s / total_s
    reason = (f"{len(estimates_s)} measurements take {total_s / 3600:.1f} h of station time, over "
              f"{LONG_PLAN_S / 3600:.0f} h; the costliest {len(costly)} take {share:.0%} of it: "
              f"{named}{more}")  # fmt: skip
    return [Finding(False, "plan_h", round(total_s / 3600, 1), reason,
                    "drop or shorten the named points (their positions, frequencies or window), or split the "
                    "design over several sessions")]  # fmt: skip
