"""Uncertainty budget of identified coefficients after the GUM (JCGM 100:2008).

A budget holds, for a vector of coefficients y = f(x), one row per input quantity:

- Type A (GUM 4.2): the least-squares fit itself; its covariance is sigma^2 (X^T W X)^-1
  (seed 000 eq. 22) with nu = n - p degrees of freedom (eq. 21);
- Type B (GUM 4.3): every measured or specified input x_i with value, standard
  uncertainty u(x_i) and its degrees of freedom (infinite unless stated), with the
  sensitivity c_i = dy/dx_i obtained by re-running the identification at x_i +- u(x_i)
  (central difference of the exact model, GUM 5.1.3 note 2).

Combined standard uncertainty (GUM eq. 10/13): Cov(y) = Cov_A + sum_i c_i c_i^T u^2(x_i)
(+ the correlated pairs given as one block); effective degrees of freedom by the
Welch-Satterthwaite formula (GUM eq. G.2b) nu_eff = u_c^4 / sum_i (c_i u_i)^4 / nu_i;
coverage factor k = t_{(1+p)/2}(nu_eff) from Student's t (GUM G.3) and expanded
uncertainty U = k u_c (GUM 6.2).

Student's t assumes the output near normal. Where rectangular inputs carry much of u_c^2 it is not (GUM G.2.3:
one dominant rectangular input makes the output nearly rectangular, whose 95 % point is 1.65 u, not 1.96 u), so
k is t_{(1+p)/2}(nu_eff) times q_p / z_p: q_p the p coverage point of the sum of the contributions with their
stated shapes (rectangular as stated, every other input and the fit normal), by numerical convolution (JCGM 101
for the linearised model), z_p the normal's. With no rectangular input q_p = z_p and k is t's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import scipy.stats

from station.coefficients import COVERAGE_PROBABILITY, student_k

SourceType = Literal["A", "B"]
Shape = Literal["normal", "rectangular"]
MIN_RELIABLE_DOF = 10  # below this the Type A estimate of sigma is itself uncertain by > 22 % (GUM E.4.3)
COVERAGE_RULE = (
    "k = Student's t at the Welch-Satterthwaite effective dof (GUM G.4), times q_95 / 1.96 where rectangular "
    "inputs shape the result: q_95 the 95 % point of the sum of the contributions with their stated shapes "
    "(JCGM 101 for the linearised model; 1 when every input is normal)"
)


def finite_or_none(x: float) -> float | None:
    """JSON has no infinity: an infinite dof (Type B only) is written as null with a note."""
    return float(x) if math.isfinite(x) else None


class UncertaintyError(ValueError):
    """An input to the budget that is not a finite, non-negative standard uncertainty."""


def coverage_factor(dof: float, probability: float = COVERAGE_PROBABILITY) -> float:
    """k = t_{(1+p)/2}(nu) (GUM G.3.4); the normal quantile for infinite nu."""
    if not 0.0 < probability < 1.0:
        raise UncertaintyError(f"coverage probability {probability!r}: expected 0 < p < 1")
    if not dof > 0:
        raise UncertaintyError(f"effective degrees of freedom {dof!r}: expected > 0")
    return student_k(dof, probability)


def gum_fields(u: float, dof: float, k: float, probability: float = COVERAGE_PROBABILITY) -> dict:
    """The GUM fields of one quantity in a results JSON: u, nu_eff (null when infinite), k, p and U = k u."""
    return {
        "standard_uncertainty": float(u),
        "effective_dof": finite_or_none(float(dof)),
        "effective_dof_note": "infinite (Type B only)" if math.isinf(dof) else "",
        "coverage_factor": float(k),
        "coverage_probability": probability,
        "expanded_uncertainty": float(k * u),
    }


GRID_POINTS = 4001  # of the convolution in coverage_point: its q to about 1e-4 u_c


def _grid_point(x: np.ndarray, normal_variance: float, half_widths: np.ndarray, probability: float) -> float:
    """The p point of |N(0, normal_variance) + sum U(-a_i, a_i)| on the grid x: the density convolved one box at a
    time through its cumulative, (f * box_a)(x) = (F(x + a) - F(x - a)) / 2a."""
    h = x[1] - x[0]

    def cumulative(f: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * h)])

    if math.sqrt(normal_variance) > 4 * h:
        f = scipy.stats.norm.pdf(x, scale=math.sqrt(normal_variance))
    else:
        f = np.zeros_like(x)
        f[x.size // 2] = 1.0 / h
    for a in half_widths:
        F = cumulative(f)
        f = (np.interp(x + a, x, F, left=0.0, right=F[-1]) - np.interp(x - a, x, F, left=0.0, right=F[-1])) / (2 * a)
    F = cumulative(f)
    return float(np.interp(0.5 * (1.0 + probability), F / F[-1], x))


def coverage_point(normal_variance: float, half_widths: Sequence[float] | np.ndarray, probability: float) -> float:
    """q with P(|Y| <= q) = p for Y = N(0, normal_variance) + sum_i U(-a_i, a_i), all independent and in units of
    u_c (normal_variance + sum a_i^2 / 3 = 1), by numerical convolution (`_grid_point`) as a ratio to the normal's
    point on the same grid (which cancels the grid's own error); a box narrower than 4 grid steps joins the
    normal, and with no box left q is the normal's z_p."""
    a = np.sort(np.asarray(half_widths, dtype=float))[::-1]
    total = max(normal_variance, 0.0) + float(np.sum(a**2)) / 3.0
    x = np.linspace(-1.0, 1.0, GRID_POINTS) * (float(np.sum(a)) + 8.0 * math.sqrt(total))
    h = x[1] - x[0]
    var_n = max(normal_variance, 0.0) + float(np.sum(a[a < 4 * h] ** 2) / 3.0)
    a = a[a >= 4 * h]
    z = coverage_factor(math.inf, probability)
    if a.size == 0:
        return z * math.sqrt(var_n)
    return z * _grid_point(x, var_n, a, probability) / _grid_point(x, total, np.zeros(0), probability)


def welch_satterthwaite(contributions: np.ndarray, dofs: np.ndarray) -> float:
    """nu_eff = u_c^4 / sum_i u_i^4 / nu_i for the contributions u_i = |c_i| u(x_i) (GUM eq. G.2b)."""
    u = np.asarray(contributions, dtype=float)
    nu = np.asarray(dofs, dtype=float)
    uc4 = float(np.sum(u**2)) ** 2
    finite = np.isfinite(nu) & (u > 0)
    denom = float(np.sum(u[finite] ** 4 / nu[finite]))
    return math.inf if denom == 0.0 else uc4 / denom


@dataclass(frozen=True)
class Source:
    """One row of the budget: an input quantity and its sensitivities (one per coefficient)."""

    source: str
    type: SourceType
    value: float
    standard_uncertainty: float
    unit: str
    sensitivity: np.ndarray  # dy_j / dx, one per coefficient (for Type A: ones, u given per coefficient)
    dof: float = math.inf
    note: str = ""
    in_combined: bool = True  # False: listed for the record, already inside another row (no double counting)
    contribution_override: np.ndarray | None = None  # Type A: sigma_k per coefficient
    block_cov: np.ndarray | None = None  # a row that is a whole covariance (a sub-fit's, propagated), added once
    shape: Shape = "normal"  # the input's distribution as stated (the fit and covariance rows: normal)

    @property
    def contribution(self) -> np.ndarray:
        """|c_j| u(x) per coefficient (GUM 5.1.3 u_j(y)); sqrt(diag) of a block row."""
        if self.contribution_override is not None:
            return np.asarray(self.contribution_override, dtype=float)
        if self.block_cov is not None:
            return np.sqrt(np.clip(np.diag(np.asarray(self.block_cov, dtype=float)), 0.0, None))
        return np.abs(self.sensitivity) * self.standard_uncertainty


@dataclass
class Budget:
    names: tuple[str, ...]
    values: np.ndarray
    units: Mapping[str, str]
    sources: list[Source] = field(default_factory=list)
    cov_a: np.ndarray | None = None  # full Type A covariance of the fit
    extra_cov: np.ndarray | None = None  # correlated Type B blocks (pairs with correlation), added once
    probability: float = COVERAGE_PROBABILITY

    def covariance(self) -> np.ndarray:
        """Cov(y) = Cov_A + sum_B c c^T u^2 (+ the correlated blocks), GUM eq. 13 in matrix form."""
        p = len(self.names)
        cov = np.zeros((p, p)) if self.cov_a is None else np.array(self.cov_a, dtype=float)
        for s in self.sources:
            if not s.in_combined:
                continue
            if s.block_cov is not None:
                cov += np.asarray(s.block_cov, dtype=float)
            elif s.type == "B":
                c = np.asarray(s.sensitivity, dtype=float) * s.standard_uncertainty
                cov += np.outer(c, c)
        if self.extra_cov is not None:
            cov += self.extra_cov
        return cov

    def standard_uncertainty(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance()))

    def effective_dof(self) -> np.ndarray:
        rows = [s for s in self.sources if s.in_combined]
        contrib = np.array([s.contribution for s in rows]).reshape(len(rows), len(self.names))
        dofs = np.array([s.dof for s in rows])
        out = []
        for j in range(len(self.names)):
            u = contrib[:, j]
            # the correlated blocks count as infinite-dof Type B: they enlarge u_c, not the denominator
            extra = 0.0 if self.extra_cov is None else max(float(self.extra_cov[j, j]), 0.0)
            u_all = np.append(u, math.sqrt(extra))
            out.append(welch_satterthwaite(u_all, np.append(dofs, math.inf)))
        return np.array(out)

    def shape_factors(self) -> np.ndarray:
        """q_p / z_p per coefficient (module docstring): 1 where no rectangular input contributes."""
        uc = self.standard_uncertainty()
        rect = [s for s in self.sources if s.in_combined and s.shape == "rectangular" and s.block_cov is None]
        z = coverage_factor(math.inf, self.probability)
        out = np.ones(len(self.names))
        for j in range(len(self.names)):
            a = np.array([math.sqrt(3.0) * s.contribution[j] for s in rect]) / uc[j] if uc[j] > 0 else np.zeros(0)
            a = a[a > 0]
            if a.size:  # never above 1 at p > 0.92: uniform parts flatten the tails (Cornish-Fisher: the p point
                # moves by (z^3 - 3 z) kappa / 24 with kappa < 0), so a ratio above 1 is the grid's rounding
                out[j] = min(1.0, coverage_point(1.0 - float(np.sum(a**2)) / 3.0, a, self.probability) / z)
        return out

    def coverage_factors(self) -> np.ndarray:
        """k = t_{(1+p)/2}(nu_eff) x the shape factor (module docstring)."""
        t = np.array([coverage_factor(nu, self.probability) for nu in self.effective_dof()])
        return t * self.shape_factors()

    def expanded_uncertainty(self) -> np.ndarray:
        return self.coverage_factors() * self.standard_uncertainty()

    def few_dof(self) -> list[str]:
        """Coefficients whose effective dof are below MIN_RELIABLE_DOF (the report flags them)."""
        return [n for n, nu in zip(self.names, self.effective_dof(), strict=True) if nu < MIN_RELIABLE_DOF]

    def coefficients_json(self) -> dict:
        """Per coefficient: value, unit, the GUM fields and the shape factor (k = t(nu_eff) x shape_factor)."""
        u, nu, k = self.standard_uncertainty(), self.effective_dof(), self.coverage_factors()
        shape = self.shape_factors()
        out = {}
        for j, (n, v) in enumerate(zip(self.names, self.values, strict=True)):
            fields = gum_fields(u[j], nu[j], k[j], self.probability)
            out[n] = {"value": float(v), "unit": self.units.get(n, ""), **fields, "shape_factor": float(shape[j])}
        return out

    def to_json(self) -> dict:
        return {
            "coefficients": self.coefficients_json(),
            "covariance": {"names": list(self.names), "matrix": self.covariance().tolist()},
            "budget": [
                {
                    "source": s.source,
                    "type": s.type,
                    "value": float(s.value),
                    "unit": s.unit,
                    "standard_uncertainty": float(s.standard_uncertainty),
                    "dof": finite_or_none(float(s.dof)),
                    "sensitivity": dict(zip(self.names, map(float, s.sensitivity), strict=True)),
                    "contribution": dict(zip(self.names, map(float, s.contribution), strict=True)),
                    "in_combined": s.in_combined,
                    "distribution": s.shape,
                    "note": s.note,
                }
                for s in self.sources
            ],
            "few_dof": self.few_dof(),
            "min_reliable_dof": MIN_RELIABLE_DOF,
            "coverage_factor_rule": COVERAGE_RULE,
        }


def type_a_source(names: Sequence[str], cov: np.ndarray, dof: int, note: str = "") -> Source:
    """The fit's own scatter (GUM 4.2.3): u_A(k_j) = sqrt(Cov_jj), nu = n - p."""
    sig = np.sqrt(np.diag(np.asarray(cov, dtype=float)))
    return Source(
        "least-squares fit (Type A, seed 000 eqs. 21-22)",
        "A",
        0.0,
        0.0,
        "",
        np.ones(len(names)),
        dof=float(dof),
        note=note or f"sigma^2 (X^T W X)^-1 with {dof} degrees of freedom",
        contribution_override=sig,
    )


def check_uncertainty(name: str, value: float, u: float) -> None:
    """A clear error naming the input when value or standard uncertainty are unusable."""
    if not math.isfinite(value):
        raise UncertaintyError(f"input {name!r}: value {value!r} is not a finite number")
    if not (math.isfinite(u) and u >= 0.0):
        raise UncertaintyError(f"input {name!r}: standard uncertainty {u!r}: expected a finite number >= 0")


def sensitivity(refit: Callable[[float], np.ndarray], x0: float, step: float) -> np.ndarray:
    """dy/dx by the central difference (y(x0 + h) - y(x0 - h)) / 2h of the whole identification."""
    if not step > 0:
        raise UncertaintyError(f"finite-difference step {step!r}: expected > 0")
    return (np.asarray(refit(x0 + step)) - np.asarray(refit(x0 - step))) / (2.0 * step)


def type_b_source(
    name: str,
    value: float,
    u: float,
    unit: str,
    refit: Callable[[float], np.ndarray],
    *,
    step: float | None = None,
    note: str = "",
    dof: float = math.inf,
    in_combined: bool = True,
    shape: Shape = "normal",
) -> Source:
    """A Type B row with its sensitivity from the refit at value +- step (step = u unless given)."""
    check_uncertainty(name, value, u)
    h = step if step is not None else (u if u > 0 else max(abs(value), 1.0) * 1e-6)
    c = sensitivity(refit, value, h)
    return Source(name, "B", value, u, unit, c, dof=dof, note=note, in_combined=in_combined, shape=shape)


def type_a_only(
    names: Sequence[str], values: np.ndarray, cov: np.ndarray, dof: int, units: Mapping[str, str], note: str = ""
) -> Budget:
    """A budget whose only source is the fit (methods whose Type B inputs are negligible or not stated)."""
    return Budget(
        tuple(names), np.asarray(values, dtype=float), units, [type_a_source(names, cov, dof, note)], cov_a=cov
    )


def type_a_json(
    coefficients: dict[str, dict],
    names: Sequence[str],
    values: np.ndarray,
    cov: np.ndarray,
    dof: int,
    units: Mapping[str, str],
    type_b_note: str,
) -> dict:
    """Merge the GUM fields of a budget that holds the fit alone (k from t at its dof) into each entry of
    `coefficients` (name -> {"value", "sigma", ...}); return the covariance and budget keys, with a statement of
    the Type B inputs left out (so that a reader sees they were not evaluated, not that they are zero)."""
    return merged_json(coefficients, type_a_only(names, values, cov, dof, units), type_b_note)


# ---------------------------------------------------------------- budgets of any identification (seeds 001-004)


@dataclass(frozen=True)
class Input:
    """A Type B input of an identification: its value as used, standard uncertainty u and where u comes from."""

    key: str
    label: str
    value: float
    u: float
    unit: str
    note: str = ""
    dof: float = math.inf
    shape: Shape = "normal"


def refit_sources(inputs: Sequence[Input], refit: Callable[[Mapping[str, float]], np.ndarray]) -> list[Source]:
    """One Type B row per input, c = dK/dx from the whole identification re-run with that input at x +- u and the
    others at their values (GUM 5.1.3 note 2); `refit` maps {key: value} to the coefficient vector."""
    base = {i.key: i.value for i in inputs}

    def refit_at(key: str) -> Callable[[float], np.ndarray]:
        return lambda x: refit({**base, key: x})

    return [
        type_b_source(
            i.label,
            i.value,
            i.u,
            i.unit,
            refit_at(i.key),
            note=i.note,
            dof=i.dof,
            shape=i.shape,
        )
        for i in inputs
    ]


def fit_budget(
    names: Sequence[str],
    values: np.ndarray,
    cov: np.ndarray,
    dof: int,
    units: Mapping[str, str],
    type_b: Sequence[Source] = (),
    note: str = "",
) -> Budget:
    """The budget of a least-squares identification: its fit (Type A) and its Type B rows."""
    cov = np.asarray(cov, dtype=float)
    return Budget(tuple(names), np.asarray(values, dtype=float), units, [type_a_source(names, cov, dof, note),
                  *type_b], cov_a=cov)  # fmt: skip


def transformed(budget: Budget, names: Sequence[str], values: np.ndarray, jacobian: np.ndarray,
                units: Mapping[str, str]) -> Budget:  # fmt: skip
    """The budget of y' = g(y) from that of y (GUM 5.1.2 to first order): every sensitivity c -> J c, every
    covariance C -> J C J^T, the dof of each row kept; J = dg/dy at the identified values."""
    J = np.atleast_2d(np.asarray(jacobian, dtype=float))

    def cov_of(c: np.ndarray | None) -> np.ndarray | None:
        return None if c is None else J @ np.asarray(c, dtype=float) @ J.T

    cov_a = cov_of(budget.cov_a)
    rows = []
    for s in budget.sources:
        if s.contribution_override is not None:  # the fit: its covariance is cov_a
            assert cov_a is not None  # a fit row comes with its covariance (fit_budget, with_fit)
            rows.append(replace(s, sensitivity=np.ones(len(names)), contribution_override=np.sqrt(np.diag(cov_a))))
        elif s.block_cov is not None:  # a covariance row: carried whole, no sensitivity of its own
            rows.append(replace(s, sensitivity=np.ones(len(names)), block_cov=cov_of(s.block_cov)))
        else:
            rows.append(replace(s, sensitivity=J @ np.asarray(s.sensitivity, dtype=float),
                                block_cov=cov_of(s.block_cov)))  # fmt: skip
    return Budget(tuple(names), np.asarray(values, dtype=float), units, rows, cov_a=cov_a,
                  extra_cov=cov_of(budget.extra_cov), probability=budget.probability)  # fmt: skip


def with_fit(budget: Budget, cov: np.ndarray, dof: float, note: str) -> Budget:
    """The same budget with the fit's Type A row replaced (e.g. by a noise pooled over several fits)."""
    cov = np.asarray(cov, dtype=float)
    a = type_a_source(budget.names, cov, int(dof), note)
    rows = [a if s.contribution_override is not None else s for s in budget.sources]
    return replace(budget, sources=rows, cov_a=cov)


def merged_json(coefficients: dict[str, dict], budget: Budget, type_b_note: str) -> dict:
    """Merge a budget's GUM fields into `coefficients` (name -> {"value", "sigma", ...}, "sigma" kept as the fit's
    Type A sigma) and return its covariance, budget rows and the note on the Type B inputs left out."""
    doc = budget.to_json()
    for name, fields in doc["coefficients"].items():
        entry = coefficients.setdefault(name, {})
        entry.update(fields)
        entry.setdefault("sigma", fields["standard_uncertainty"])
    return {"covariance": doc["covariance"], "budget": doc["budget"], "few_dof": doc["few_dof"],
            "type_b": type_b_note}  # fmt: skip


def stacked(first: Budget, second: Budget) -> Budget:
    """One budget of two identifications on independent data that share their Type B inputs (rows of the same
    source name: their sensitivities side by side, so the inputs' correlation between the two is kept); the
    fits' Type A rows become one block-diagonal row, which needs the two fits' dof to agree (e.g. pooled)."""
    a1, a2 = (next(s for s in b.sources if s.contribution_override is not None) for b in (first, second))
    if a1.dof != a2.dof:
        raise UncertaintyError(f"Type A dof {a1.dof:g} and {a2.dof:g} differ: one row cannot carry both")
    p1, p2 = len(first.names), len(second.names)

    def block(c1: np.ndarray | None, c2: np.ndarray | None) -> np.ndarray | None:
        if c1 is None and c2 is None:
            return None
        out = np.zeros((p1 + p2, p1 + p2))
        out[:p1, :p1] = 0.0 if c1 is None else c1
        out[p1:, p1:] = 0.0 if c2 is None else c2
        return out

    cov_a = block(first.cov_a, second.cov_a)
    assert cov_a is not None  # both have a fit row, which comes with its covariance
    rows = [type_a_source((*first.names, *second.names), cov_a, int(a1.dof), a1.note)]
    other = {s.source: s for s in second.sources if s.contribution_override is None}
    for s in first.sources:
        if s.contribution_override is not None:
            continue
        t = other.pop(s.source, None)
        c2 = np.zeros(p2) if t is None else t.sensitivity
        rows.append(replace(s, sensitivity=np.concatenate([s.sensitivity, c2]),
                            block_cov=block(s.block_cov, None if t is None else t.block_cov)))  # fmt: skip
    for t in other.values():
        rows.append(replace(t, sensitivity=np.concatenate([np.zeros(p1), t.sensitivity]),
                            block_cov=block(None, t.block_cov)))  # fmt: skip
    return Budget((*first.names, *second.names), np.concatenate([first.values, second.values]),
                  {**first.units, **second.units}, rows, cov_a=cov_a,
                  extra_cov=block(first.extra_cov, second.extra_cov), probability=first.probability)  # fmt: skip
