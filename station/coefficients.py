"""Coefficient tables and the fit-check lines from any method's results JSON, for the console, notebooks and reports.

Methods report coefficients in one of two shapes:

    {"coefficients": {name: {"value", "sigma"}}, "units": {name: unit}, "mu", "mu_c", "reliable", ...}
    {name: {"value", "sigma", "unit"}, ...}

`coefficient_rows` reads both (any depth), so a new method is shown with its units
as soon as it states them. `sigma` is the standard uncertainty of the least-squares
fit alone (Type A, k = 1): the covariance (X^T X)^-1 scaled by the residual sigma^2
(seed 000 eqs. 21-22). Where the method has a GUM budget (procedures.common.uncertainty;
every method of seeds 000-004 has one) a coefficient also has `standard_uncertainty`
(Type A and B combined), `coverage_factor` k (Student's t at the Welch-Satterthwaite
effective degrees of freedom, so k varies from coefficient to coefficient: 2.57 at 5 dof,
1.96 for a Type B dominated one), `coverage_probability` and `expanded_uncertainty`
U = k u: then u, k and U are the budget's, read as stated, never a fixed k. A result
without those fields (an old results file with the fit alone) gets k = Student's t at the
fit's residual degrees of freedom (the result's `dof`), printed beside U; a row with no
stated dof gets no U (a fixed k would claim a coverage nobody evaluated).
`mu` is max|e| / sigma and `mu_c = 1.25 + ln sqrt(N / 3)` its critical value
(seed 000 eq. 28): mu < mu_c says that no residual is an outlier.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Any

import scipy.stats

COVERAGE_PROBABILITY = 0.95  # of every expanded uncertainty U = k u
UNCERTAINTY_NOTE = (
    "u is the standard uncertainty (k = 1, about 68 %): the GUM budget's combined Type A and B where the method "
    "has one, else the fit's covariance scaled by the residual sigma (seed 000 eq. 22); U = k u is the expanded "
    "uncertainty, about 95 %, with its coverage factor k shown: Student's t at the budget's effective degrees of "
    "freedom, else at the fit's residual degrees of freedom"
)


def student_k(dof: float, probability: float = COVERAGE_PROBABILITY) -> float:
    """k = t_{(1+p)/2}(nu) (GUM G.3.4): Student's t at nu degrees of freedom, the normal quantile for infinite nu."""
    q = 0.5 * (1.0 + probability)
    return float(scipy.stats.norm.ppf(q) if math.isinf(dof) else scipy.stats.t.ppf(q, dof))


MU_NOTE = "mu = max|residual| / sigma; mu_c = 1.25 + ln sqrt(N/3) (seed 000 eq. 28); mu < mu_c: no outlier"


@dataclass(frozen=True)
class CoefficientRow:
    """One identified quantity: value and standard uncertainty u (k = 1) in `unit`."""

    result: str  # the results key it came from ("integral", "baseline", "20C", ...)
    name: str
    value: float | None
    u: float | None  # standard uncertainty, k = 1 (the budget's where there is one, else the fit's)
    unit: str
    note: str = ""
    k: float | None = None  # coverage factor of `expanded`; None: no dof stated, so no U
    stated_expanded: float | None = None  # U as the method states it (GUM budget), if it does
    u_fit: float | None = None  # the least-squares fit's own standard uncertainty (Type A only)
    probability: float | None = None  # coverage probability of U, when the method states it

    @property
    def expanded(self) -> float | None:
        """U = k u: the method's own where it states one, else k u with k from the fit's dof (None without)."""
        if self.stated_expanded is not None:
            return self.stated_expanded
        return None if self.u is None or self.k is None else self.k * self.u

    @property
    def budgeted(self) -> bool:
        """Whether u and U come from a GUM budget (Type A and B) rather than the fit alone."""
        return self.stated_expanded is not None

    @property
    def relative(self) -> float | None:
        """u / |value|, None when either is missing or the value is zero."""
        if self.u is None or not self.value:
            return None
        return self.u / abs(self.value)


def _number(x: Any) -> float | None:
    return float(x) if isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) else None


def _is_quantity(doc: Any) -> bool:
    return isinstance(doc, Mapping) and "value" in doc and (doc["value"] is None or _number(doc["value"]) is not None)


# The lab's names carry their unit as a suffix (`_s`, `_hz`, `_rad`, ...): the unit of a quantity whose
# method states none, read from its own name or its parent's ("hysteresis_g", "harmonics_rad": {"c1": ...}).
SUFFIX_UNITS = (("_g_per_s", "g/s"), ("_radps", "rad/s"), ("_mps2", "m/s^2"), ("_arcsec", "arcsec"),
                ("_ppm", "ppm"), ("_rad", "rad"), ("_deg", "deg"), ("_hz", "Hz"), ("_m", "m"), ("_s", "s"),
                ("_g", "g"), ("_v", "V"), ("_c", "°C"))  # fmt: skip


def suffix_unit(*names: str) -> str:
    """The unit named by the suffix of the first of `names` that has one of SUFFIX_UNITS, else ""; a name
    ending in `_per_s` is a rate of the next name's unit ("drift_per_s" of "bias_g": g/s)."""
    if names and names[0].lower().endswith("_per_s"):
        return f"{suffix_unit(names[0][: -len('_per_s')], *names[1:]) or '1'}/s"
    for name in names:
        for suffix, unit in SUFFIX_UNITS:
            if name.lower().endswith(suffix):
                return unit
    return ""


def coefficient_rows(results: Mapping[str, Any]) -> list[CoefficientRow]:
    """Every quantity with a value in the results (either shape of the module docstring), in order; a quantity
    stated twice in one result (plain, then with its GUM budget or unit) once, in its fullest form."""
    best: dict[tuple[str, str], CoefficientRow] = {}
    for row in _walk(results, "", {}, None):
        key = (_block(row.result), row.name)
        old = best.get(key)
        if old is None or (row.budgeted, bool(row.unit)) > (old.budgeted, bool(old.unit)):
            best[key] = row if old is None else replace(row, result=old.result)
    return list(best.values())


def _walk(doc: Mapping[str, Any], where: str, units: Mapping[str, Any], dof: float | None) -> Iterator[CoefficientRow]:
    """The quantities under `doc`, each with the units and the fit's residual `dof` stated at its level or above."""
    own_units = doc.get("units")
    units = {**units, **own_units} if isinstance(own_units, Mapping) else dict(units)
    own_dof = _number(doc.get("dof"))
    dof = own_dof if own_dof is not None and own_dof > 0 else dof
    for key, item in doc.items():
        if key == "coefficients" and isinstance(item, Mapping):
            yield from _walk(item, where, units, dof)
        elif _is_quantity(item):
            unit = str(item.get("unit") or units.get(key) or suffix_unit(key, where.rsplit(".", 1)[-1]))
            yield _row(where or key, key, item, unit, dof)
        elif isinstance(item, Mapping) and key != "units":
            yield from _walk(item, f"{where}.{key}" if where else key, units, dof)
        elif isinstance(item, list):  # per-block results (one per temperature, setup, ...)
            for i, element in enumerate(item):
                if isinstance(element, Mapping):
                    yield from _walk(element, f"{where}.{key}[{i}]" if where else f"{key}[{i}]", units, dof)


def _block(path: str) -> str:
    """The result a quantity belongs to: its path up to the last list index ("eight_point.temperatures[2]"),
    else its first key ("integral")."""
    cut = path.rfind("]")
    return path[: cut + 1] if cut >= 0 else path.split(".")[0]


def _row(result: str, name: str, item: Mapping[str, Any], unit: str, dof: float | None) -> CoefficientRow:
    sigma = _number(item.get("sigma"))
    u = _number(item.get("standard_uncertainty"))
    big_u, k = _number(item.get("expanded_uncertainty")), _number(item.get("coverage_factor"))
    if u is None or big_u is None or k is None:  # the fit alone: Student's t at its residual dof, if stated
        return CoefficientRow(result, name, _number(item["value"]), sigma, unit, str(item.get("note", "")),
                              k=None if dof is None else student_k(dof), u_fit=sigma,
                              probability=None if dof is None else COVERAGE_PROBABILITY)  # fmt: skip
    probability = _number(item.get("coverage_probability"))
    return CoefficientRow(result, name, _number(item["value"]), u, unit, str(item.get("note", "")), k=k,
                          stated_expanded=big_u, u_fit=sigma, probability=probability)  # fmt: skip


def acceptance(results: Mapping[str, Any]) -> list[tuple[str, bool, str]]:
    """(result, accepted, reason) for every result that reports mu and mu_c (seed 000 eq. 28)."""
    out = []
    for name, doc in results.items():
        if not isinstance(doc, Mapping):
            continue
        mu, mu_c = _number(doc.get("mu")), _number(doc.get("mu_c"))
        if mu is None or mu_c is None:
            continue
        ok = bool(doc.get("reliable", mu < mu_c))
        n = doc.get("n_points")
        pts = f", {n} points" if n is not None else ""
        out.append((name, ok, f"{name}: mu {mu:.2f} {'<' if ok else '>='} mu_c {mu_c:.2f}" +
                    (" (no outlier)" if ok else " (an outlier among the residuals)") + pts))  # fmt: skip
    return out


def conclusion(
    state: str, results: dict | None, faults: list[str] | tuple[str, ...] = (), certificate: bool = False
) -> list[str]:
    """The run, the fit check (mu against mu_c: an outlier among the residuals, seed 000 eq. 28) and conformity,
    each on its own line: passing the fit check says nothing about the limits, and a method that reports no
    outlier test passes nothing."""
    run = f"run: {state}" + (f"; {len(faults)} fault{'s' if len(faults) != 1 else ''}: {faults[0]}" if faults
                             else ", no fault")  # fmt: skip
    checks = acceptance(results or {})
    if results is None:
        fit = "fit check: none (no analysis for this run)"
    elif not checks:
        fit = "fit check: none (this method reports no outlier test, mu against mu_c; no outlier was looked for)"
    else:
        passed = all(ok for _, ok, _ in checks)
        fit = f"fit check: {'passed' if passed else 'FAILED'}: " + "; ".join(r for _, _, r in checks)
    where = "the certificate beside the report" if certificate else "no certificate for this run"
    conformity = f"conformity against the instrument's limits: not decided by the fit check; see {where}"
    return [run, fit, conformity]


def format_value(x: float | None, digits: int = 7) -> str:
    """A value in scientific notation, or a dash when there is none."""
    return "—" if x is None else f"{x:+.{digits - 1}e}"


def format_rows(rows: list[CoefficientRow]) -> list[str]:
    """Console lines: name = value unit, u and U = k u in the same unit, u/|value|."""
    lines = []
    width = max((len(r.name) for r in rows), default=4)
    for r in rows:
        if r.value is None:
            lines.append(f"  {r.name:{width}s}   not identified{f' ({r.note})' if r.note else ''}")
            continue
        unit = f" {r.unit}" if r.unit else " (unit not stated by the method)"
        text = f"  {r.name:{width}s} = {format_value(r.value)}{unit}"
        if r.u is not None:
            rel = f", u/|value| = {r.relative:.1e}" if r.relative is not None else ""
            p = f", {100 * r.probability:.0f} %" if r.probability is not None else ""
            big_u = ("U not stated (no degrees of freedom)" if r.expanded is None or r.k is None
                     else f"U = {r.expanded:.2e}{unit} (k = {r.k:.2f}{p})")  # fmt: skip
            text += f"   u = {r.u:.2e}{unit}, {big_u}{rel}"
            if r.budgeted and r.u_fit is not None:
                text += f"; fit alone {r.u_fit:.2e}"
        if r.note:
            text += f"; {r.note}"
        lines.append(text)
    return lines
