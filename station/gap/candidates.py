"""The library of candidate effects: every registered effect (station.twin.effects), as fittable parameters.

Each candidate names the twin effect it switches on and the parameters that
are fitted, those its module declares with a typical magnitude (`scale`, from
seed 000 Tables 5-7 and section 6.1 where the seed gives one) used for
scaling the fit and for the design-level identifiability report, a
finite-difference step and a plausible bound. Parameters that are set instead
of fitted (`fixed`, declared with a nominal value) take the twin's value when
the twin has the effect on, else the nominal one; a module's notes say why a
parameter is not fitted (the rates see it only through another, or not at all).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

from station.twin.config import TwinConfig
from station.twin.effects import EFFECTS, Effect


@dataclass(frozen=True)
class FreeParam:
    """One fitted parameter: effect.param = value_at_twin + scale * u."""

    effect: str
    param: str
    unit: str
    scale: float  # typical magnitude (seed 000 where given)
    fd_step: float  # finite-difference step in parameter units
    bound: float = float("inf")  # largest physically plausible |value| (a fit beyond it explains nothing)
    timing: bool = False  # fixed by the period identities, not counted in the rates' degrees of freedom

    @property
    def key(self) -> str:
        return f"{self.effect}.{self.param}"


@dataclass(frozen=True)
class Candidate:
    name: str
    free: tuple[FreeParam, ...]
    fixed: Mapping[str, float] = field(default_factory=dict)  # set, not fitted: nominal values
    notes: str = ""

    @property
    def effect(self) -> Effect:
        return EFFECTS[self.name]

    @property
    def cause(self) -> str:
        return self.effect.cause


@functools.cache
def as_candidate(effect: Effect) -> Candidate:
    """An effect as a candidate: its parameters with a typical size fitted, those with a nominal value set."""
    free = []
    for k, p in effect.params.items():
        if p.typical is not None:
            free.append(FreeParam(effect.name, k, p.unit, p.typical, p.typical * p.fd_fraction, p.bound, p.timing))
    return Candidate(effect.name, tuple(free), effect.nominal, effect.notes)


class _Library(Mapping[str, Candidate]):
    """The candidates of the registered effects (station.twin.effects.EFFECTS), in its order."""

    def __getitem__(self, name: str) -> Candidate:
        return as_candidate(EFFECTS[name])

    def __iter__(self) -> Iterator[str]:
        return iter(EFFECTS)

    def __len__(self) -> int:
        return len(EFFECTS)


LIBRARY: Mapping[str, Candidate] = _Library()


def library(exclude: Sequence[str] = ()) -> list[Candidate]:
    """Candidates in table order, but those excluded (for blind validation: an effect left out)."""
    unknown = [n for n in exclude if n not in LIBRARY]
    if unknown:
        raise ValueError(f"unknown candidate effect(s) {unknown}; known: {', '.join(LIBRARY)}")
    return [c for n, c in LIBRARY.items() if n not in exclude]


def fixed_params(candidate: Candidate, twin: TwinConfig) -> dict[str, float]:
    """Parameters of the candidate's effect that are set, not fitted: the twin's value where it is on."""
    return {k: twin.param(candidate.name, k) or nominal for k, nominal in candidate.fixed.items()}


def apply(
    twin: TwinConfig, free: Sequence[FreeParam], values: Sequence[float], fixed: Mapping[str, Mapping[str, float]]
) -> TwinConfig:
    """The twin with each free parameter set to `values` (parameter units) and fixed ones set."""
    per_effect: dict[str, dict[str, float]] = {}
    for eff, params in fixed.items():
        per_effect.setdefault(eff, {}).update(params)
    for fp, v in zip(free, values, strict=True):
        per_effect.setdefault(fp.effect, {})[fp.param] = float(v)
    cfg = twin
    for eff, params in per_effect.items():
        current = dict(twin.effects.get(eff, {}))
        current.update(params)
        cfg = cfg.with_effect(eff, **current)
    return cfg


def twin_values(twin: TwinConfig, free: Sequence[FreeParam]) -> list[float]:
    """Current values of the free parameters in the twin (0 or the default when the effect is off)."""
    out = []
    for fp in free:
        if fp.effect in twin.effects:
            out.append(float(twin.effects[fp.effect][fp.param]))
        else:
            out.append(float(EFFECTS[fp.effect].defaults[fp.param]))
    return out
