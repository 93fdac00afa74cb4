"""Attribution: each candidate added to the twin and fitted with the calibrated coefficients, ranked.

Forward selection. At each step every candidate not yet chosen (and with at
least one parameter the calibrated terms do not absorb:
station.gap.identifiability) is fitted jointly with the calibrated
coefficients and the effects already chosen (station.gap.fit.fit_model), then
- evidence: the F-test of the rate channel, F = (dRSS / m) / (RSS / dof),
  with m the candidate's fitted rate parameters; for the other channels (period
  identities, grating harmonics) the chi-square test of their d chi^2 with as
  many dof as the candidate has parameters acting there; a candidate acting on
  both takes the smaller p-value times 2;
- information criterion: BIC = n_r ln(RSS_r / n_r) + chi^2_other + k ln(n_rows).
A candidate is accepted when its p-value is below ALPHA / (number tested at that
step) (Bonferroni), it lowers the BIC and every fitted parameter is within its
physically plausible bound (station.gap.candidates, at 2 sigma); among those the lowest
BIC wins unless the pulse record (station.gap.rawstreams.PulseRecord, when the session has one) rejects it:
each such candidate's fitted twin is tested against the rate harmonics of the pulse edges
(station.gap.localise.pulse_goodness_of_fit) at the verdict's level, and one that leaves them
significantly inconsistent is rejected (`rejected_by` names the test) and the next one is tried;
when the pulse record rejects every one, the rates' best is taken (the pulses may show a second
effect still missing, as in a pair: the verdict's own pulse test, after the selection, decides).
Another candidate within bounds that reproduces the winner's fit on every channel
(its chi^2, rate rows in the winner's sigma^2, within REPRODUCE_CHI2 of the winner's;
the pulse record not rejecting it) is a rival: this session does not tell them apart.
Selection stops at max_effects; one more step then says whether a further effect would
still have been accepted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from station.gap import candidates as cl
from station.gap.fit import Linearisation, ModelFit, fit_model
from station.gap.localise import pulse_goodness_of_fit

ALPHA = 0.01
AMBIGUOUS_DBIC = 6.0
MAX_EFFECTS = 3
# A rival reproduces the winner when the data prefer the winner by less than a 1-dof test at ALPHA.
REPRODUCE_CHI2 = float(stats.chi2.isf(ALPHA, 1))
BOUND_SIGMAS = 2.0


@dataclass
class Scored:
    """One candidate fitted on top of a reference model."""

    name: str
    fit: ModelFit
    F: float
    p_value: float
    bic: float
    dbic: float  # vs the reference model (negative = better)
    drss_sigma2: float  # rate dRSS in units of the reference sigma0^2
    dchi2_tau: float  # of the other channels (period identities and grating)
    rivals: list[str] = field(default_factory=list)  # reproduce the winner (REPRODUCE_CHI2) when chosen
    beyond_bounds: list[str] = field(default_factory=list)  # parameters fitted beyond their plausible bound
    profiled: dict[str, float] = field(default_factory=dict)  # set parameters chosen by profile (fr, Q)
    rejected_by: str = ""  # the test of another channel that rejects this candidate's fit (the pulse record)

    @property
    def plausible(self) -> bool:
        return not self.beyond_bounds


def beyond_bounds(fit: ModelFit, name: str, w_radps: np.ndarray) -> list[str]:
    """Parameters of effect `name` whose fitted |value| exceeds its bound by more than BOUND_SIGMAS sd, and its
    joint bound (station.twin.effects.base.JointBound, such as the waveform's Zs1(w) = z0 + z1 w) at the design's
    vibration frequencies w."""
    rows = zip(fit.free, fit.values, fit.sigmas, strict=True)
    out = [fp.param for fp, v, sd in rows if fp.effect == name and abs(v) - BOUND_SIGMAS * sd > fp.bound]
    keys = [fp.key for fp in fit.free]
    jb = cl.LIBRARY[name].effect.joint_bound
    if jb is not None and {f"{name}.{k}" for k in jb.params} <= set(keys):
        j = [keys.index(f"{name}.{k}") for k in jb.params]
        n_lin = fit.J.shape[1] - len(fit.free)
        scale = np.array([fit.free[i].scale for i in j])
        cov = fit.cov[np.ix_([n_lin + i for i in j], [n_lin + i for i in j])] * np.outer(scale, scale)
        A = jb.columns(w_radps)
        combo, sd = A @ fit.values[j], np.sqrt(np.clip(np.einsum("ij,jk,ik->i", A, cov, A), 0, None))
        if np.any(np.abs(combo) - BOUND_SIGMAS * sd > jb.bound):
            out.append(jb.label)
    return out


def chi2_total(fit: ModelFit, s2_rate: float) -> float:
    return fit.rss_rate / s2_rate + fit.chi2_tau + fit.chi2_grating


def _timing_params(fit: ModelFit) -> int:
    return sum(1 for fp in fit.free if fp.timing)


def _other_params(fit: ModelFit, n_rate: int) -> int:
    """Free parameters whose columns move the timing or grating rows."""
    n_lin = fit.J.shape[1] - len(fit.free)
    return int(np.sum(np.linalg.norm(fit.J[n_rate:, n_lin:], axis=0) > 0))


def bic(fit: ModelFit, n_rate: int, n_other: int) -> float:
    """Schwarz's criterion of the joint fit (the timing and grating chi^2 are whitened by their noise)."""
    k = fit.n_rate_params + _timing_params(fit)
    chi2_other = fit.chi2_tau + fit.chi2_grating
    return n_rate * math.log(fit.rss_rate / n_rate) + chi2_other + k * math.log(n_rate + n_other)


def score(ref: ModelFit, fit: ModelFit, name: str, n_rate: int, n_other: int, w_radps: np.ndarray) -> Scored:
    """Evidence for adding candidate `name` (fit) to the reference model (ref); w_radps: the design's
    vibration frequencies (for beyond_bounds)."""
    m_rate = fit.n_rate_params - ref.n_rate_params
    drss = ref.rss_rate - fit.rss_rate
    F, p_rate = math.nan, 1.0
    if m_rate > 0 and fit.dof_rate > 0:
        F = (drss / m_rate) / (fit.rss_rate / fit.dof_rate)
        p_rate = float(stats.f.sf(F, m_rate, fit.dof_rate)) if F > 0 else 1.0
    m_other = _other_params(fit, n_rate) - _other_params(ref, n_rate)
    dchi = (ref.chi2_tau + ref.chi2_grating) - (fit.chi2_tau + fit.chi2_grating)
    p_other = float(stats.chi2.sf(dchi, m_other)) if m_other > 0 and dchi > 0 else 1.0
    p = p_rate
    if m_other > 0:
        p = min(1.0, 2.0 * min(p_rate, p_other)) if m_rate > 0 else p_other
    b_ref, b = bic(ref, n_rate, n_other), bic(fit, n_rate, n_other)
    s0 = ref.rss_rate / max(ref.dof_rate, 1)
    return Scored(name, fit, F, p, b, b - b_ref, drss / s0, dchi, beyond_bounds=beyond_bounds(fit, name, w_radps))


@dataclass
class Selection:
    chosen: list[Scored]
    steps: list[list[Scored]]  # every candidate scored at each step, best BIC first
    final: ModelFit
    capped: bool = False  # a further effect would still be accepted beyond max_effects
    alternatives: list[list[str]] = field(default_factory=list)  # other models reproducing it (station.gap.subsets)

    @property
    def effects(self) -> list[str]:
        return [s.name for s in self.chosen]


# Grid of the lateral resonance's frequency and quality factor profiled before kx is fitted (seed 000 6.1.4).
LATERAL_FR_HZ = tuple(float(x) for x in np.geomspace(0.5, 100.0, 41))
LATERAL_Q = (0.7, 1.5, 3.0, 6.0, 12.0, 25.0, 50.0)


def _gain2(f_hz: np.ndarray, fr_hz: float | np.ndarray, q: float | np.ndarray) -> np.ndarray:
    """(L(f) / L0)^2 = 1 / ((1 - (f / fr)^2)^2 + (f / (Q fr))^2) (physics.md, lateral_resonance)."""
    r = f_hz / fr_hz
    return 1.0 / ((1.0 - r * r) ** 2 + (r / q) ** 2)


def _lateral_gains(
    lin: Linearisation, current: ModelFit, frs, qs, bounded: bool = True
) -> list[tuple[float, float, float]]:
    """(chi^2 removed, fr, Q) of the kx column at every (fr, Q) of the grid, off the current model: kx aO^2 has
    window mean kx L(f)^2 a^2 <sin^2>, so its column at (fr, Q) is the linearisation's kx column with each
    vibration row scaled by L(f)^2 / L(f; twin)^2. bounded: only where kx stays within its plausible bound."""
    key = "lateral_resonance.kx"
    d, ch = lin.ch.design, lin.ch
    fr0, q0 = lin.base_cfg.param("lateral_resonance", "fr"), lin.base_cfg.param("lateral_resonance", "Q")
    f = np.concatenate([d.freq_hz, np.zeros(ch.n_other)])
    col0 = lin.columns[key]
    bound = lin.param(key).bound
    J = current.J[:, np.linalg.norm(current.J, axis=0) > 0]
    Q, _ = np.linalg.qr(J / np.linalg.norm(J, axis=0))
    r = current.r_white
    grid = [(float(fr), float(q)) for fr in frs for q in qs]
    fr_hz, q = (np.array(x)[:, None] for x in zip(*grid, strict=True))
    # The kx column at every grid point, one row each (elementwise, the same floats as one point at a time).
    cols = col0 * np.where(f > 0, _gain2(f, fr_hz, q) / _gain2(f, fr0, q0), 0.0)
    out = []
    for c, at in zip(cols, grid, strict=True):
        c = c - Q @ (Q.T @ c)
        cc = float(c @ c)
        if cc <= 0 or (bounded and abs(float(c @ r) / cc) > bound):  # kx beyond its plausible bound
            continue
        out.append((float(c @ r) ** 2 / cc, *at))
    return out


def lateral_profile(lin: Linearisation, current: ModelFit) -> dict[str, float] | None:
    """fr and Q of a lateral resonance by profile (_lateral_gains): the (fr, Q) whose column removes the most
    chi^2 with kx within its plausible bound (None without one): first on the coarse grid, then on a fine one
    around its best point (a sharp resonance falls between coarse points)."""
    if "lateral_resonance.kx" not in lin.columns:
        return None

    def best_of(frs, qs, bounded: bool) -> dict[str, float] | None:
        gains = _lateral_gains(lin, current, frs, qs, bounded)
        if not gains:
            return None
        _, fr, q = max(gains)
        return {"fr": fr, "Q": q}

    step = LATERAL_FR_HZ[1] / LATERAL_FR_HZ[0]
    q_fine = np.geomspace(LATERAL_Q[0], LATERAL_Q[-1], 31)
    # The region from the coarse grid whatever kx (a sharp peak may need the fine grid to come within
    # bounds), then the fine grid within bounds; failing that, the coarse grid within bounds.
    for bounded in (False, True):
        coarse = best_of(LATERAL_FR_HZ, LATERAL_Q, bounded)
        if coarse is None:
            continue
        fine = best_of(np.geomspace(coarse["fr"] / step, coarse["fr"] * step, 21), q_fine, True)
        if fine is not None:
            return fine
    return None


# The rates cannot tell apart the (fr, Q) whose chi^2 removed is within the 2-dof test at ALPHA of the best;
# among them the pulse record chooses (their 2nd harmonic kx L(f)^2 a^2 / 2 per frequency measures L(f)).
LATERAL_REGION_CHI2 = float(stats.chi2.isf(ALPHA, 2))
LATERAL_PULSE_TRIES = 12
LATERAL_REGION_GRID = (np.geomspace(0.5, 100.0, 81), np.geomspace(LATERAL_Q[0], LATERAL_Q[-1], 15))


def lateral_pulse_profile(
    lin: Linearisation,
    current: ModelFit,
    names: Sequence[str],
    drop: frozenset[str],
    over: Mapping[str, Mapping[str, float]],
    level: float,
) -> tuple[dict[str, float], ModelFit] | None:
    """fr and Q chosen by the pulse record within the rates' region (LATERAL_REGION_CHI2): up to
    LATERAL_PULSE_TRIES of its points, spread over it by rank, each fitted with `names`; the one whose
    fit the pulse test accepts with the highest p-value (at least level), or None."""
    gains = sorted(_lateral_gains(lin, current, *LATERAL_REGION_GRID), reverse=True)
    region = [g for g in gains if g[0] > gains[0][0] - LATERAL_REGION_CHI2] if gains else []
    best: tuple[float, dict[str, float], ModelFit] | None = None
    for _, fr, q in region[:: max(1, math.ceil(len(region) / LATERAL_PULSE_TRIES))]:
        o = {"fr": fr, "Q": q}
        fit = fit_model(lin, names, drop=drop, fixed_override={**over, "lateral_resonance": o})
        det = pulse_goodness_of_fit(lin.ch, fit) if fit.dof_rate > 0 else None
        if det is not None and det.p_value >= level and (best is None or det.p_value > best[0]):
            best = (det.p_value, o, fit)
    return None if best is None else (best[1], best[2])


def _scored(
    lin: Linearisation, current: ModelFit, fit: ModelFit, name: str, profiled: Mapping[str, float] | None
) -> Scored:
    """Candidate `name`'s fit scored on top of `current` (score), with its set parameters chosen by profile."""
    d = lin.ch.design
    w_radps = 2 * math.pi * np.unique(d.freq_hz[d.vib])
    sc = score(current, fit, name, lin.ch.n_rate, lin.ch.n_other, w_radps)
    sc.profiled = dict(profiled or {})
    return sc


def _kept_profiles(
    profiled: Mapping[str, Mapping[str, float]], chosen: Sequence[str]
) -> dict[str, Mapping[str, float]]:
    """The profiled set parameters of the effects already chosen (kept in later steps)."""
    return {n: v for n, v in profiled.items() if n in chosen}


def _fit_candidate(
    lin: Linearisation,
    current: ModelFit,
    chosen: Sequence[str],
    name: str,
    drop: frozenset[str],
    profiled: Mapping[str, Mapping[str, float]],
) -> Scored | None:
    """Candidate `name` fitted with the chosen effects and scored (a lateral resonance at its fr, Q by profile,
    lateral_profile); None where the fit leaves no rate degree of freedom."""
    override = profiled.get(name)
    if name == "lateral_resonance" and override is None:
        override = lateral_profile(lin, current)
    over = {name: override} if override else {}
    over |= _kept_profiles(profiled, chosen)
    fit = fit_model(lin, [*chosen, name], drop=drop, fixed_override=over)
    return _scored(lin, current, fit, name, override) if fit.dof_rate > 0 else None


def _accepted(scored: list[Scored], limit: float) -> list[Scored]:
    """The candidates the rates accept: p-value below limit, a lower BIC, every parameter within its bound."""
    return [s for s in scored if s.p_value < limit and s.dbic < 0 and s.plausible]


def _lateral_by_pulses(
    lin: Linearisation,
    current: ModelFit,
    chosen: Sequence[str],
    drop: frozenset[str],
    profiled: Mapping[str, Mapping[str, float]],
    scored: list[Scored],
    limit: float,
    pulse_level: float,
) -> list[Scored]:
    """`scored` again where the pulse record rejects an accepted lateral resonance at the rates' fr, Q: with the fr, Q
    that the pulses choose within what the rates cannot tell apart (lateral_pulse_profile), where they find one."""
    ok = _accepted(scored, limit)
    lateral = next((s for s in ok if s.name == "lateral_resonance" and s.name not in profiled), None)
    if lateral is None or not rejected_by_pulses(lin, lateral, pulse_level):
        return scored
    over = _kept_profiles(profiled, chosen)
    alt = lateral_pulse_profile(lin, current, [*chosen, lateral.name], drop, over, pulse_level)
    if alt is None:
        return scored
    sc = _scored(lin, current, alt[1], lateral.name, alt[0])
    return sorted([sc if s is lateral else s for s in scored], key=lambda s: s.bic)


def _rivals(lin: Linearisation, scored: list[Scored], best: Scored, pulse_level: float) -> list[str]:
    """The candidates within bounds that reproduce the winner on every channel: the rates (in the winner's sigma^2),
    timing and grating in the fit within REPRODUCE_CHI2 of the winner's chi^2, the pulse record not rejecting them."""
    s2 = best.fit.rss_rate / max(best.fit.dof_rate, 1)
    chi_best = chi2_total(best.fit, s2)
    alike = [s for s in scored if s is not best and s.plausible and chi2_total(s.fit, s2) - chi_best < REPRODUCE_CHI2]
    return [s.name for s in alike if not rejected_by_pulses(lin, s, pulse_level)]


def _step(
    lin: Linearisation,
    current: ModelFit,
    chosen: Sequence[str],
    names: Sequence[str],
    drop: frozenset[str],
    profiled: Mapping[str, Mapping[str, float]] | None = None,
    pulse_level: float = ALPHA,
) -> tuple[list[Scored], Scored | None]:
    """Score every candidate of `names` on top of `current`; the accepted one, if any.

    profiled: the profiled set parameters of candidates already chosen (kept in later steps);
    pulse_level: a candidate whose fit the pulse test rejects below it is not accepted."""
    profiled = dict(profiled or {})
    fitted = (_fit_candidate(lin, current, chosen, name, drop, profiled) for name in names)
    scored = sorted((s for s in fitted if s is not None), key=lambda s: s.bic)
    limit = ALPHA / max(len(scored), 1)
    scored = _lateral_by_pulses(lin, current, chosen, drop, profiled, scored, limit, pulse_level)
    ok = _accepted(scored, limit)
    if not ok:
        return scored, None
    # The pulse record rejecting all of them may show a second effect still missing (a pair): the rates' best.
    best = next((s for s in ok if not rejected_by_pulses(lin, s, pulse_level)), ok[0])
    best.rivals = _rivals(lin, scored, best, pulse_level)
    return scored, best


def rejected_by_pulses(lin: Linearisation, s: Scored, level: float) -> bool:
    """Test the candidate's fit against the pulse record (if any); record and return a rejection below level."""
    if lin.ch.pulses is None:
        return False
    det = pulse_goodness_of_fit(lin.ch, s.fit)
    if det is not None and det.p_value < level:
        s.rejected_by = f"pulse_goodness_of_fit (chi^2 / dof = {det.F:.1f} on {det.dof[0]} dof, p = {det.p_value:.1e})"
    return bool(s.rejected_by)


def forward_select(
    lin: Linearisation,
    base: ModelFit,
    names: Sequence[str],
    drop: frozenset[str],
    max_effects: int = MAX_EFFECTS,
    pulse_level: float = ALPHA,
    start: Sequence[Scored] = (),
    first_step: list[Scored] | None = None,
) -> Selection:
    """Greedy forward selection of effects over candidates `names`; pulse_level: that of the pulse test (_step).

    start: effects already chosen (their last one's fit the current model), scored on the base as first_step."""
    current = start[-1].fit if start else base
    chosen, steps = list(start), [] if first_step is None else [first_step]
    remaining = [n for n in names if n not in {s.name for s in start}]
    while remaining:
        profiled = {s.name: s.profiled for s in chosen if s.profiled}
        scored, best = _step(lin, current, [s.name for s in chosen], remaining, drop, profiled, pulse_level)
        if len(chosen) == max_effects:
            return Selection(chosen, steps, current, capped=best is not None)
        steps.append(scored)
        if best is None:
            break
        chosen.append(best)
        current = best.fit
        remaining.remove(best.name)
    return Selection(chosen, steps, current)
