"""Attribution: each candidate added to the twin and fitted with the calibrated coefficients, ranked.

Forward selection. At each step every candidate not yet chosen (and with at
least one parameter the calibrated terms do not absorb:
gap.identifiability) is fitted jointly with the calibrated
coefficients and the effects already chosen (gap.fit.fit_model), then
- evidence: the F-test of the rate channel, F = (dRSS / m) / (RSS / dof),
  with m the candidate's fitted rate parameters; for the period identities
  (frequency_error) the chi-square test of d chi^2_tau with 1 dof; a
  candidate acting on both channels takes the smaller p-value times 2;
- information criterion: BIC = n_r ln(RSS_r / n_r) + chi^2_tau + k ln(n_r + n_tau).
A candidate is accepted when its p-value is below ALPHA / (number tested at that
step) (Bonferroni) and it lowers the BIC; among those the lowest BIC wins.
Candidates whose BIC is within AMBIGUOUS_DBIC of the winner's (short of
"strong" evidence, Kass and Raftery 1995) are its rivals: this session does
not tell them apart. Selection stops at max_effects; one more
step then says whether a further effect would still have been accepted.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from scipy import stats

from gap.fit import Linearisation, ModelFit, fit_model

ALPHA = 0.01
AMBIGUOUS_DBIC = 6.0
MAX_EFFECTS = 3


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
    dchi2_tau: float
    rivals: list[str] = field(default_factory=list)  # within AMBIGUOUS_DBIC when chosen


def _timing_params(fit: ModelFit) -> int:
    return sum(1 for fp in fit.free if fp.effect == "frequency_error")


def bic(fit: ModelFit, n_rate: int, n_tau: int) -> float:
    """Schwarz's criterion of the joint rate and period-identity fit (the timing chi^2 has known sigma)."""
    k = fit.n_rate_params + _timing_params(fit)
    return n_rate * math.log(fit.rss_rate / n_rate) + fit.chi2_tau + k * math.log(n_rate + n_tau)


def score(ref: ModelFit, fit: ModelFit, name: str, n_rate: int, n_tau: int) -> Scored:
    """Evidence for adding candidate `name` (fit) to the reference model (ref)."""
    m_rate = fit.n_rate_params - ref.n_rate_params
    drss = ref.rss_rate - fit.rss_rate
    F, p_rate = math.nan, 1.0
    if m_rate > 0 and fit.dof_rate > 0:
        F = (drss / m_rate) / (fit.rss_rate / fit.dof_rate)
        p_rate = float(stats.f.sf(F, m_rate, fit.dof_rate)) if F > 0 else 1.0
    acts_on_tau = _timing_params(fit) > _timing_params(ref)
    dchi = ref.chi2_tau - fit.chi2_tau
    p_tau = float(stats.chi2.sf(dchi, 1)) if acts_on_tau and dchi > 0 else 1.0
    p = p_rate
    if acts_on_tau:
        p = min(1.0, 2.0 * min(p_rate, p_tau)) if m_rate > 0 else p_tau
    b_ref, b = bic(ref, n_rate, n_tau), bic(fit, n_rate, n_tau)
    s0 = ref.rss_rate / max(ref.dof_rate, 1)
    return Scored(name, fit, F, p, b, b - b_ref, drss / s0, dchi)


@dataclass
class Selection:
    chosen: list[Scored]
    steps: list[list[Scored]]  # every candidate scored at each step, best BIC first
    final: ModelFit
    capped: bool = False  # a further effect would still be accepted beyond max_effects

    @property
    def effects(self) -> list[str]:
        return [s.name for s in self.chosen]


def _step(
    lin: Linearisation,
    current: ModelFit,
    chosen: Sequence[str],
    names: Sequence[str],
    drop: frozenset[str],
) -> tuple[list[Scored], Scored | None]:
    """Score every candidate of `names` on top of `current`; the accepted one, if any."""
    d = lin.ch.design
    n_rate, n_tau = d.n_points, int(d.vib.sum())
    scored = []
    for name in names:
        fit = fit_model(lin, [*chosen, name], drop=drop)
        if fit.dof_rate > 0:
            scored.append(score(current, fit, name, n_rate, n_tau))
    scored.sort(key=lambda s: s.bic)
    limit = ALPHA / max(len(scored), 1)
    ok = [s for s in scored if s.p_value < limit and s.dbic < 0]
    if not ok:
        return scored, None
    best = ok[0]
    best.rivals = [s.name for s in scored if s is not best and s.bic - best.bic < AMBIGUOUS_DBIC]
    return scored, best


def forward_select(
    lin: Linearisation,
    base: ModelFit,
    names: Sequence[str],
    drop: frozenset[str],
    max_effects: int = MAX_EFFECTS,
) -> Selection:
    """Greedy forward selection of effects over candidates `names`."""
    current, chosen, steps = base, [], []
    remaining = list(names)
    while remaining:
        scored, best = _step(lin, current, [s.name for s in chosen], remaining, drop)
        if len(chosen) == max_effects:
            return Selection(chosen, steps, current, capped=best is not None)
        steps.append(scored)
        if best is None:
            break
        chosen.append(best)
        current = best.fit
        remaining.remove(best.name)
    return Selection(chosen, steps, current)
