"""What one effect of physics.md's table declares, as a plug-in (station.twin.effects lists them).

An effect is data: its parameters (unit, default, typical size, plausible bound), the direction the
validation injects it in, the texts the report shows, and the terms it adds to the twin (`Terms`). The twin
(station.twin.inputs, station.twin.measurement), the gap diagnosis's candidates, `station gap-validate` and the report
read nothing else about it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

Params = Mapping[str, float]


@dataclass(frozen=True)
class Param:
    """One parameter. `typical` (seed 000/003 where given) makes it fitted by the gap diagnosis, scaled by it, with
    a finite-difference step of fd_fraction x typical; `nominal` makes it set instead of fitted (the twin's value
    where the twin has the effect on, else this); a parameter with neither comes from the twin."""

    unit: str
    default: float = 0.0
    typical: float | None = None
    bound: float = math.inf  # largest physically plausible |value| (a fit beyond it explains nothing)
    fd_fraction: float = 1e-2
    nominal: float | None = None
    raw_measures: str = ""  # what a raw stream (piga-session/1 raw/) measures of it directly
    timing: bool = False  # fixed by the period identities: not counted in the rates' degrees of freedom


@dataclass(frozen=True)
class JointBound:
    """A plausible bound on a linear combination sum_k c_k(w) p_k over the design's vibration frequencies w (rad/s),
    such as the waveform's Zs1(w) = z0 + z1 w: `columns(w)` gives c(w) for `params`, one column each."""

    label: str
    params: tuple[str, ...]
    columns: Callable[[np.ndarray], np.ndarray]
    bound: float


@dataclass(frozen=True)
class Terms:
    """The effect's terms in the twin (physics.md, the table's "model change"), each None when it has none.

    table_harmonics(p, w_radps): (j, Zsj, Zcj) added to z(t);
    static_angle_rad(p, theta_rad): added to theta_e at indexing position theta;
    motion_angle_rad(p, psi): added to theta_e over the crank phase (alpha_x);
    lateral_accel_mps2(p, psi, w_radps, A0_m): a_lat;
    rate_radps(p, aI, aP, aO): added to the instrument rate w_out;
    frequency_offset(p): eps_f of w = w_cmd (1 + eps_f);
    reference_latency_s(p): added to every reference-crossing stamp;
    bias_slope_radps2(p): d of k0 + d t_session.
    """

    table_harmonics: Callable[[Params, float], Sequence[tuple[int, float, float]]] | None = None
    static_angle_rad: Callable[[Params, float], float] | None = None
    motion_angle_rad: Callable[[Params, np.ndarray], np.ndarray] | None = None
    lateral_accel_mps2: Callable[[Params, np.ndarray, float, float], np.ndarray] | None = None
    rate_radps: Callable[[Params, np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None
    frequency_offset: Callable[[Params], float] | None = None
    reference_latency_s: Callable[[Params], float] | None = None
    bias_slope_radps2: Callable[[Params], float] | None = None


@dataclass(frozen=True, eq=False)  # one object per effect: hashed by identity
class Effect:
    """One effect: name and cause (physics.md's table), parameters, validation injection, report texts, terms.

    injection: the direction the validation injects it in (parameter values before scaling to a SNR; the
    `nominal` of set parameters joins it); explanation: what it means at the station, for the report;
    separating: the test points that tell it from its look-alikes; notes: what the diagnosis does not fit, and
    why; aliases: the effects that enter the twin exactly as this one does (physics.md), named beside it; check(params):
    a message when a parameter set is impossible, else "".
    """

    name: str
    cause: str
    params: Mapping[str, Param]
    injection: Mapping[str, float]
    explanation: str
    separating: str
    terms: Terms = field(default_factory=Terms)
    notes: str = ""
    joint_bound: JointBound | None = None
    aliases: tuple[str, ...] = ()
    pulse_phase: str = ""  # a phase only the pulse edges see (window means do not): profiled in their test
    pulse_folded: tuple[str, str] | None = None  # (effect, parameter) the rates fold a set parameter into; the
    # pulse edges see it apart, so their test profiles it within that parameter's bound unless that effect is chosen
    check: Callable[[Params], str] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))
        object.__setattr__(self, "injection", MappingProxyType(dict(self.injection)))
        unknown = set(self.injection) - set(self.params)
        if unknown:
            raise ValueError(f"effect {self.name!r}: injection of unknown parameter(s) {sorted(unknown)}")

    @property
    def defaults(self) -> Mapping[str, float]:
        return {k: p.default for k, p in self.params.items()}

    @property
    def nominal(self) -> Mapping[str, float]:
        """The parameters set, not fitted, at their nominal values."""
        return {k: p.nominal for k, p in self.params.items() if p.nominal is not None}
