"""Attribution: each candidate added to the twin and fitted with the calibrated coefficients, ranked.

Forward selection. At each step every candidate not yet chosen (and not
absorbed: station.gap.identifiability) is fitted jointly with the calibrated
coefficients and the effects already chosen (station.gap.fit.fit_model), then
- evidence: the F-test of the rate channel, F = (dRSS / m) / (RSS / dof),
  with m the candidate's fitted rate parameters; for the period identities
  (frequency_error) the chi-square test of d chi^2_tau with 1 dof; a
  candidate acting on both channels takes the smaller p-value times 2;
- information criterion: BIC = n_r ln(RSS_r / n_r) + chi^2_tau + k ln(n_r + n_tau);
- held-out gap and shrink (station.gap.heldout).
A candidate is accepted when its p-value is below ALPHA / (number tested at that
step) (Bonferroni) and it lowers the BIC; among those the lowest BIC wins.
Candidates whose BIC is within AMBIGUOUS_DBIC of the winner's are named as
not separable from it by this session.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from station.gap.fit import Linearisation, ModelFit, fit_model

ALPHA = 0.01
AMBIGUOUS_DBIC = 2.0
MAX_EFFECTS = 3


@dataclass
class Scored:
    """One candidate fitted on top of a reference model."""

    name: str
    fit: ModelFit
    m_rate: int
    F: float
    p_rate: float
    p_tau: float
    p_value: float
    bic: float
    dbic: float  # vs the reference model (negative = better)
    drss_sigma2: float  # rate dRSS in units of the reference sigma0^2
    dchi2_tau: float
    heldout_G: float = math.nan
    heldout_shrink: float | None = None
    extra: dict = field(default_factory=dict)


def bic(fit: ModelFit, n_rate: int, n_tau: int) -> float:
    k = fit.n_rate_params + sum(1 for fp in fit.free if fp.effect == "frequency_error")
    return n_rate * math.log(fit.rss_rate / n_rate) + fit.chi2_tau + k * math.log(n_rate + n_tau)


def score(ref: ModelFit, fit: ModelFit, name: str, n_rate: int, n_tau: int) -> Scored:
    """Evidence for adding candidate `name` (fit) to the reference model (ref)."""
    m_rate = fit.n_rate_params - ref.n_rate_params
    drss = ref.rss_rate - fit.rss_rate
    F, p_rate = math.nan, 1.0
    if m_rate > 0 and fit.dof_rate > 0:
        F = (drss / m_rate) / (fit.rss_rate / fit.dof_rate)
        p_rate = float(stats.f.sf(F, m_rate, fit.dof_rate)) if F > 0 else 1.0
    acts_on_tau = any(fp.effect == "frequency_error" for fp in fit.free) and not any(
        fp.effect == "frequency_error" for fp in ref.free
    )
    dchi = ref.chi2_tau - fit.chi2_tau
    p_tau = float(stats.chi2.sf(dchi, 1)) if acts_on_tau and dchi > 0 else 1.0
    if acts_on_tau and m_rate > 0:
        p = min(1.0, 2.0 * min(p_rate, p_tau))
    elif acts_on_tau:
        p = p_tau
    else:
        p = p_rate
    b_ref, b = bic(ref, n_rate, n_tau), bic(fit, n_rate, n_tau)
    s0 = ref.rss_rate / max(ref.dof_rate, 1)
    return Scored(name, fit, m_rate, F, p_rate, p_tau, p, b, b - b_ref, drss / s0, dchi)


@dataclass
class Selection:
    chosen: list[Scored]
    steps: list[list[Scored]]  # every candidate scored at each step
    final: ModelFit
    ambiguous: list[str]  # candidates not separable from the first chosen effect


def forward_select(
    lin: Linearisation,
    base: ModelFit,
    names: Sequence[str],
    drop: frozenset[str],
    start: dict[str, float],
    max_effects: int = MAX_EFFECTS,
) -> Selection:
    """Greedy forward selection of effects over candidates `names`."""
    d = lin.ch.design
    n_rate, n_tau = d.n_points, int(d.vib.sum())
    current, chosen, steps = base, [], []
    remaining = list(names)
    ambiguous: list[str] = []
    while remaining and len(chosen) < max_effects:
        scored = []
        for name in remaining:
            effs = [s.name for s in chosen] + [name]
            fit = fit_model(lin, effs, drop=drop, start=start)
            if fit.dof_rate <= 0:
                continue
            scored.append(score(current, fit, name, n_rate, n_tau))
        scored.sort(key=lambda s: s.bic)
        steps.append(scored)
        limit = ALPHA / max(len(scored), 1)
        ok = [s for s in scored if s.p_value < limit and s.dbic < 0]
        if not ok:
            break
        best = ok[0]
        if not chosen:
            ambiguous = [s.name for s in scored if s is not best and s.bic - best.bic < AMBIGUOUS_DBIC]
        chosen.append(best)
        current = best.fit
        remaining.remove(best.name)
    return Selection(chosen, steps, current, ambiguous)


def rank_table(step: list[Scored]) -> list[Scored]:
    """Candidates of one step, best information criterion first."""
    return sorted(step, key=lambda s: (s.bic, -np.nan_to_num(s.drss_sigma2)))
