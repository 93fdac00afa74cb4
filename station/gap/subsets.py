"""Models the greedy forward selection does not reach: a pair of effects against one candidate absorbing both.

Forward selection (station.gap.attribute) adds at each step the candidate that lowers the BIC most. A candidate with
many parameters can absorb two weaker effects at once and end the selection: on 6 positions the four index
harmonics the design can fit take any static pattern over the positions, a mount tilt's and a bias drift's
alike (../shared/gap-devset case c05bc5fc: index_harmonics chosen, BIC -1005.0, against -1008.6 for
mount_misalignment + bias_drift).

Every pair of the first step's POOL best candidates within their bounds that lower the BIC alone is fitted
jointly with the calibrated coefficients (station.gap.fit.fit_model); pairs with the greedy's first choice are left
out (its next step scored them). A pair is a model when each member is significant given the other (the
test of station.gap.attribute.score at ALPHA / pairs, and a lower BIC), every parameter is within its plausible bound
and the pulse record (when there is one) does not reject the fit. Among the greedy choice and these models
the lowest BIC wins, and the selection continues from it; every other one that reproduces it on every
channel (chi^2, rate rows in its sigma^2, within REPRODUCE_CHI2: the rule of a rival) is an alternative:
the session cannot tell them apart (station.gap.verdict names them all).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import combinations

import numpy as np

from station.gap.attribute import (
    ALPHA,
    REPRODUCE_CHI2,
    Scored,
    Selection,
    bic,
    chi2_total,
    forward_select,
    rejected_by_pulses,
    score,
)
from station.gap.fit import Linearisation, ModelFit, fit_model

POOL = 5  # pairs are tried among this many of the first step's best accepted candidates


def _pool(step: list[Scored], skip: str) -> list[Scored]:
    """The POOL candidates of lowest BIC within their bounds that lower the BIC alone (a member may be
    significant only given the other), but `skip`: the greedy's first choice, whose pairs its next step scored."""
    return [s for s in step if s.plausible and s.dbic < 0 and s.name != skip][:POOL]


def _pair(lin: Linearisation, a: Scored, b: Scored, drop: frozenset[str], n_pairs: int):
    """The pair (a, b) as a model: (its Scored members, a first, and its fit), or None (station.gap.subsets docstring;
    the pulse test is left to the caller)."""
    over = {s.name: s.profiled for s in (a, b) if s.profiled}
    fit = fit_model(lin, [a.name, b.name], drop=drop, fixed_override=over)
    if fit.dof_rate <= 0:
        return None
    d = lin.ch.design
    w_radps = 2 * math.pi * np.unique(d.freq_hz[d.vib])
    n_rate, n_other = lin.ch.n_rate, lin.ch.n_other
    a_given_b = score(b.fit, fit, a.name, n_rate, n_other, w_radps)
    b_given_a = score(a.fit, fit, b.name, n_rate, n_other, w_radps)
    limit = ALPHA / max(n_pairs, 1)
    if any(s.p_value >= limit or s.dbic >= 0 or not s.plausible for s in (a_given_b, b_given_a)):
        return None
    b_given_a.profiled = dict(b.profiled)
    return [a, b_given_a], fit


def _models(
    lin: Linearisation, greedy: Selection, drop: frozenset[str], level: float
) -> list[tuple[list[Scored], ModelFit]]:
    """The greedy choice and every pair model of the first step's pool (_pool, _pair) that the pulse record does
    not reject, lowest BIC first."""
    pool = _pool(greedy.steps[0], greedy.effects[0])
    pairs = [(a, b) for a, b in combinations(pool, 2) if {a.name, b.name} != set(greedy.effects)]
    models: list[tuple[list[Scored], ModelFit]] = [(greedy.chosen, greedy.final)]
    models += [m for a, b in pairs if (m := _pair(lin, a, b, drop, len(pairs))) is not None]
    models.sort(key=lambda m: bic(m[1], lin.ch.n_rate, lin.ch.n_other))
    # The pulse record (when there is one) tests every pair model; the greedy's choice met it in its own steps.
    return [m for m in models if m[0] is greedy.chosen or not rejected_by_pulses(lin, m[0][-1], level)]


def _reproducing(models: list[tuple[list[Scored], ModelFit]]) -> list[list[str]]:
    """The effects of every model after the first that reproduces its fit on every channel (chi^2, rate rows in
    its sigma^2, within REPRODUCE_CHI2: the rule of a rival)."""
    best_fit = models[0][1]
    s2 = best_fit.rss_rate / max(best_fit.dof_rate, 1)
    chi_best = chi2_total(best_fit, s2)
    return [[s.name for s in members] for members, fit in models[1:] if chi2_total(fit, s2) - chi_best < REPRODUCE_CHI2]


def best_subset(
    lin: Linearisation,
    base: ModelFit,
    greedy: Selection,
    names: Sequence[str],
    drop: frozenset[str],
    max_effects: int,
    level: float,
) -> Selection:
    """The greedy selection, or the pair model of lower BIC continued by forward selection; either way with
    the models that reproduce it as its alternatives (station.gap.subsets docstring). level: the pulse test's."""
    if not greedy.chosen or not greedy.steps or max_effects < 2:
        return greedy
    models = _models(lin, greedy, drop, level)
    best_members = models[0][0]
    out = greedy
    if best_members is not greedy.chosen:
        first = greedy.steps[0]
        out = forward_select(lin, base, names, drop, max_effects, level, start=best_members, first_step=first)
    out.alternatives = _reproducing(models)
    return out
