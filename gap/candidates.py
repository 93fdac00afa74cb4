"""The library of candidate effects: every effect of physics.md's table, as fittable parameters.

Each candidate names the twin effect it switches on (models.config.EFFECTS)
and the parameters that are fitted, each with a typical magnitude (`scale`,
from seed 000 Tables 5-7 and section 6.1 where the seed gives one) used for
scaling the fit and for the design-level identifiability report, and a
finite-difference step. Parameters that are set instead of fitted (`fixed`)
take the twin's value when the twin has the effect on, else a nominal value.

Two parameters of the table are never fitted by the rate data:
- parasitic_rotation ax0 enters exactly as dtheta_mount does (theta_e =
  theta + dtheta_mount + ax0 + ...), so it is folded into mount_misalignment;
- lateral_resonance sees L0 and kx only as kx L0^2 (the window mean of
  kx aO^2), and phiL not at all; kx is fitted with L0 fixed, fr and Q from the twin.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from models.config import EFFECTS, TwinConfig


@dataclass(frozen=True)
class FreeParam:
    """One fitted parameter: effect.param = value_at_twin + scale * u."""

    effect: str
    param: str
    unit: str
    scale: float  # typical magnitude (seed 000 where given)
    fd_step: float  # finite-difference step in parameter units
    bound: float = float("inf")  # largest physically plausible |value| (a fit beyond it explains nothing)

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
    def cause(self) -> str:
        return EFFECTS[self.name].cause


def _fp(effect: str, param: str, scale: float, step_fraction: float = 1e-2, bound: float | None = None) -> FreeParam:
    """bound: the largest plausible magnitude, BOUND_FACTOR x the typical one unless the physics says otherwise."""
    b = BOUND_FACTOR * scale if bound is None else bound
    return FreeParam(effect, param, EFFECTS[effect].parameters[param], scale, scale * step_fraction, b)


# A lab's plausible range: an order of magnitude above the typical size (seed 000 Tables 5-7, 6.1).
BOUND_FACTOR = 10.0
# What the table does at each frequency, Zs1(w) = z0 + z1 w, within the same bound as z0: Table 5 measured
# |Zs1| <= 88 um over 2-10 Hz (z0 and z1 each within bounds can still add to half a millimetre at 7 Hz).
ZS1_BOUND_M = 1.5e-4
ARCSEC_RAD = 4.84813681109536e-06


def _library() -> dict[str, Candidate]:
    # seed 003: arc-second angle errors of an indexing head; 20" at most.
    idx = tuple(_fp("index_harmonics", f"{p}{k}", 5e-6, bound=20 * ARCSEC_RAD) for k in range(1, 5) for p in ("c", "s"))
    cands = [
        # seed 000 eq. 32: Zs1 = -0.1299 mm + 0.0032 mm s/rad * w; Zc1 not given, 50 um assumed. A waveform
        # error is micrometres to a tenth of a millimetre (Table 5: |Zs1| <= 88 um over 2-10 Hz on a 30 mm
        # crank): bounds just above eq. 32's own intercept and slope, never ten times them (1.3 mm).
        Candidate(
            "waveform_fundamental",
            (
                _fp("waveform_fundamental", "z0", 1.3e-4, bound=1.5e-4),
                _fp("waveform_fundamental", "z1", 3.2e-6, bound=4e-6),
                _fp("waveform_fundamental", "Zc1", 5e-5, bound=1.5e-4),
            ),
        ),
        # seed 000 Table 5: Zs2, Zc2 up to about 0.05 mm; third harmonic assumed half of that.
        Candidate(
            "waveform_harmonics",
            (
                _fp("waveform_harmonics", "Zs2", 2e-5, bound=1e-4),
                _fp("waveform_harmonics", "Zc2", 2e-5, bound=1e-4),
                _fp("waveform_harmonics", "Zs3", 1e-5, bound=1e-4),
                _fp("waveform_harmonics", "Zc3", 1e-5, bound=1e-4),
            ),
        ),
        # seed 000 Table 7: axs1 = -0.92", axc1 = 0.19"; a table top rocking by 1' at most.
        Candidate(
            "parasitic_rotation",
            (
                _fp("parasitic_rotation", "axs1", 4.5e-6, bound=60 * ARCSEC_RAD),
                _fp("parasitic_rotation", "axc1", 1e-6, bound=60 * ARCSEC_RAD),
            ),
            notes="ax0 is not fitted: it enters exactly as dtheta_mount (see mount_misalignment)",
        ),
        # seed 000 6.1.4: kx about 1e-5 rad/s/g^2; kx L0^2 up to 5e-7 (kx 2e-4 at 5 % lateral motion).
        Candidate(
            "lateral_resonance",
            (_fp("lateral_resonance", "kx", 1e-5, bound=5e-3),),
            fixed={"L0": 0.01},  # 1 % lateral motion
            notes="only kx L0^2 is seen: L0 is fixed, fr and Q come from the twin, phiL has no effect on window means",
        ),
        # instrument terms of a PIGA: 1e-6 to 1e-5 rad/s/g^2, 1e-4 at most.
        Candidate("odd_quadratic", (_fp("odd_quadratic", "koq", 1e-6, bound=1e-4),)),
        Candidate("cross_coupling", (_fp("cross_coupling", "kip", 1e-6, bound=1e-4),)),
        Candidate("index_harmonics", idx),  # seed 003: arc-second angle errors
        # seed 000 5.x: installation errors should stay below 1e-3 rad; 300" at most.
        Candidate("mount_misalignment", (_fp("mount_misalignment", "dtheta_mount", 1e-3, bound=300 * ARCSEC_RAD),)),
        # about 1e-6 rad/s of bias wander over a 7 h session; at most a drift as large as k0 (1e-4 rad/s in 3 h).
        Candidate("bias_drift", (_fp("bias_drift", "d", 4e-11, 1.0, bound=1e-8),)),
        # a read head's electronics: microseconds, a millisecond at most.
        Candidate("readhead_latency", (_fp("readhead_latency", "delta", 1e-5, bound=1e-3),)),
        # seed 000 Table 6: sigma_f / f up to 2e-5; a drive's frequency error 5e-4 at most.
        Candidate("frequency_error", (_fp("frequency_error", "eps_f", 1e-5, 1e-4, bound=5e-4),)),
    ]
    return {c.name: c for c in cands}


LIBRARY: Mapping[str, Candidate] = _library()


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
