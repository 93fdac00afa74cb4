"""The verdict: no gap beyond noise, explained by effect(s) X, not explained, or cannot tell.

Evidence of a gap (before any effect is added), two families each at level
ALPHA with a Bonferroni correction inside it:
- a library candidate significant in the forward selection (station.gap.attribute), accepted or
  rejected by another test (beyond its plausible bounds, or by the pulse record);
- the residual checks: the structure tests on the twin's residuals
  (station.gap.localise) and excess scatter, the residual noise of the fit
  against a reference: the pure error of repeats when there are any
  (lack-of-fit F test), else the twin's own noise model (chi-square test);
  none when neither exists.
"explained": effects were accepted, after them no residual check is
significant, the held-out gap shrank by at least
MIN_SHRINK (when there was a held-out gap to shrink), and each effect is one
this design can tell from the others: no rival reproducing its fit within its bounds on
every channel (station.gap.attribute), no alternative model reproducing the chosen set (station.gap.subsets),
and none of its significant parameters is one that only the static points see where the
session has no pulse record to test it (station.gap.identifiability.seen_only_at_rest). Parameters
the design does not fix (absorbed, aliased, unseen) are named as undetermined; one effect
whose held-out points alone fix some of its parameters is still `explained`, and says so.
"cannot_tell": the effects that explain the gap are ones this design cannot tell
apart (it names them all with their look-alikes and alternatives, and the test points
that would separate them), or several whose split only the held-out points fix, or
one it sees only at rest (the table's rest value, which out-of-library motions share)
together with a look-alike. A `cannot_tell` always names at least two effects (issue 28;
Verdict checks it when made). Otherwise "unexplained", naming what was found and what
remains, and which test rejected the library's best candidate (its parameters' bounds,
or the pulse record): among them a design that leaves fewer than MIN_DOF residual
degrees of freedom after the calibrated terms (nothing can be tested), and effects
the session sees only at rest that no library look-alike reproduces (an out-of-library
motion with that rest value fits the same, so they are not `explained` either).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from station.gap import candidates as cl
from station.gap.attribute import ALPHA, Selection
from station.gap.identifiability import PULSE_TEST_HOW, IdentifiabilityReport
from station.gap.localise import Detector, significant

MIN_SHRINK = 0.5
MIN_DOF = 4
# The chosen effects leave more than this fraction of the held-out rows that the twin predicts unpredictable
# (station.gap.heldout.UNPREDICTABLE_EIG): the design fixes their parameters only with the held-out points themselves.
MAX_UNPREDICTABLE = 0.1
# Held-out rows of a right model are chi-square_1 (se of their mean sqrt(2 / rows)). The limit is loose:
# a nonlinear effect fitted on a grid (lateral fr, Q) leaves up to ~6 se at SNR 30 on tests/indep sessions,
# while an overfitted one (8 index harmonics on few positions) predicts held-out positions at 1000 se.
HELDOUT_AFTER_SE = 20.0


@dataclass(frozen=True)
class NoiseCheck:
    reference: str  # "pure error of repeats" | "twin noise model" | "none"
    sigma_ref_radps: float | None
    p_value: float | None


class VerdictError(RuntimeError):
    """A verdict that breaks issue 28's rule for `cannot_tell` (a bug of the diagnosis, not of its input)."""


@dataclass
class Verdict:
    verdict: str  # no_gap | explained | unexplained | cannot_tell
    effects: list[str]  # the effects added (explained only)
    text: str
    partial: list[str] = field(default_factory=list)  # accepted, but the gap is not explained
    remaining: list[str] = field(default_factory=list)  # what is left after them
    ambiguous: list[str] = field(default_factory=list)  # effects this design cannot tell apart
    undetermined: dict[str, list[str]] = field(default_factory=dict)  # parameters the design does not fix
    separating: list[str] = field(default_factory=list)  # test points that would separate the ambiguous effects

    def __post_init__(self) -> None:
        if self.verdict == "cannot_tell":
            _check_cannot_tell(self)

    def to_json(self) -> dict:
        return {
            "verdict": self.verdict,
            "verdict_text": self.text,
            "effects": self.effects,
            "partial_effects": self.partial,
            "remaining": self.remaining,
            "ambiguous_effects": self.ambiguous,
            "undetermined_parameters": self.undetermined,
            "separating_points": self.separating,
        }


def _check_cannot_tell(v: Verdict) -> None:
    """Issue 28: `cannot_tell` names at least two effects that it cannot tell apart (each in its text), and
    no effect as explaining the gap; one effect alone is `explained` or `unexplained`."""
    named = list(dict.fromkeys(v.ambiguous))
    if len(named) < 2 or v.effects:
        raise VerdictError(f"cannot_tell must name at least two effects and explain none: {named}, {v.effects}")
    missing = [e for e in named if e not in v.text]
    if missing:
        raise VerdictError(f"cannot_tell names {', '.join(missing)} but its text does not: {v.text}")


def residual_checks(dets: list[Detector], noise: NoiseCheck) -> list[str]:
    """The structure tests and the excess-scatter test significant as one family (Bonferroni at ALPHA)."""
    level = family_level(len(dets))  # significant() divides by len(dets)
    found = [f"{d.label} (F = {d.F:.1f}, p = {d.p_value:.1e})" for d in significant(dets, level)]
    if noise.p_value is not None and noise.p_value < ALPHA / (len(dets) + 1):
        found.append(f"excess scatter against the {noise.reference} (p = {noise.p_value:.1e})")
    return found


def family_level(n_tests: int) -> float:
    """The level at which significant() flags a member of a family of n_tests structure tests plus the noise
    check (Bonferroni at ALPHA over n_tests + 1)."""
    return ALPHA * n_tests / (n_tests + 1)


def _aliases(name: str) -> tuple[str, ...]:
    """The effects that enter the twin exactly as `name` does (its module's `aliases`, physics.md)."""
    return cl.LIBRARY[name].effect.aliases


def _look_alikes(selection: Selection) -> dict[str, list[str]]:
    """For each chosen effect, the candidates that reproduce its fit within their bounds on every channel,
    and its exact aliases unless chosen too."""
    chosen = {s.name for s in selection.chosen}
    out = {}
    for s in selection.chosen:
        alike = list(s.rivals) + [a for a in _aliases(s.name) if a not in s.rivals and a not in chosen]
        if alike:
            out[s.name] = alike
    return out


def _rejected(selection: Selection) -> list[str]:
    """Candidates that the rates would accept but another test rejects: parameters beyond their plausible
    bounds, or the pulse record (station.gap.attribute): those of the last step, and chosen ones the pulses reject
    (taken because the pulses rejected every candidate of their step)."""
    if not selection.steps:
        return []
    last = selection.steps[-1]
    limit = ALPHA / max(len(last), 1)
    chosen = [c for c in selection.chosen if c.rejected_by]
    out = []
    for s in chosen + [s for s in last if s.p_value < limit and s.dbic < 0]:
        if s.beyond_bounds:
            out.append(f"{s.name} fits only at an implausible {', '.join(s.beyond_bounds)}")
        elif s.rejected_by:
            out.append(f"{s.name} fits the rates but is rejected by {s.rejected_by}")
    return out


def _aliases_chosen(effects: list[str]) -> bool:
    """Whether the chosen effects include an exact alias of one another."""
    return any(a in effects for e in effects for a in _aliases(e))


def _rest_only_text(rest_only: dict[str, list[str]]) -> str:
    parts = "; ".join(f"{e} through {', '.join(ps)}" for e, ps in rest_only.items())
    return (
        f"the gap is fitted by {parts}, which this session sees only at rest (the static points; its window "
        "means in vibration vanish), so it shows only the table's rest value: any motion with that value at "
        f"rest (a tilt at 2 psi, out of the library, among them) fits the same; {PULSE_TEST_HOW}"
    )


def _named(effects: list[str], alike: dict[str, list[str]], alternatives: list[list[str]]) -> list[str]:
    """The chosen effects, each followed by its look-alikes, then the effects of every alternative model; once each."""
    named = [n for e in effects for n in [e, *alike.get(e, [])]] + [n for alt in alternatives for n in alt]
    return list(dict.fromkeys(named))


def _separating(
    ident: IdentifiabilityReport, named: list[str], rest_only: dict[str, list[str]], alternatives: list[list[str]]
) -> list[str]:
    """The test points that would separate the named effects (found where the search for them ran)."""
    return ident.separating_tests(named) if len(named) > 1 or rest_only or alternatives else []


def _separating_text(points: list[str]) -> str:
    """The separating test points as a clause of the verdict's text ("" if none)."""
    return f"; test points that would separate them: {'; '.join(points)}" if points else ""


def _not_told_apart(
    effects: list[str], alike: dict[str, list[str]], alternatives: list[list[str]], sh: str, sep: list[str]
) -> Verdict:
    """cannot_tell: the effects explain the gap, but this session cannot tell them from their look-alikes and the
    alternative models that reproduce them."""
    text = f"cannot tell with this design: the gap is explained ({sh}) by {', '.join(effects)}, but this session "
    why = _look_alikes_text(effects, alike, alternatives)
    named = _named(effects, alike, alternatives)
    return Verdict(
        "cannot_tell", [], f"{text}cannot tell {why}{_separating_text(sep)}", ambiguous=named, separating=sep
    )


def _look_alikes_text(effects: list[str], alike: dict[str, list[str]], alternatives: list[list[str]]) -> str:
    """Each effect with the look-alikes it cannot be told from, then the alternative models that reproduce them."""
    return "; ".join(
        [f"{e} from {', '.join(a)}" for e, a in alike.items()]
        + [f"{' + '.join(effects)} from {' + '.join(alt)} (which reproduces it)" for alt in alternatives]
    )


def _with_look_alikes(effects: list[str], alike: dict[str, list[str]], alternatives: list[list[str]]) -> str:
    """The look-alikes as a clause of a verdict's text ("" if none)."""
    why = _look_alikes_text(effects, alike, alternatives)
    return f"; nor can it tell {why}" if why else ""


def _explained(
    effects: list[str], ident: IdentifiabilityReport, sh: str, unpredictable: bool, heldout_rows: tuple[int, int] | None
) -> Verdict:
    """explained, naming the parameters this design does not determine, and saying where only the held-out points
    fix some of them."""
    undetermined = {e: ident.undetermined(e) for e in effects if ident.undetermined(e)}
    text = f"explained by {', '.join(effects)} ({sh})"
    if undetermined:
        text += "; not determined by this design (absorbed, aliased with the fitted ones or unseen): " + (
            "; ".join(f"{e} {', '.join(ps)}" for e, ps in undetermined.items())
        )
    if unpredictable:
        text += f"; {_unpredictable_text(heldout_rows)}, so no held-out test checks the fitted parameters"
    return Verdict("explained", effects, text, undetermined=undetermined)


def _seen_only_at_rest(
    effects: list[str], rest_only: dict[str, list[str]], sh: str, named: list[str], sep: list[str], alike: str
) -> Verdict:
    """The chosen effects fit the gap through parameters the session sees only at rest: `cannot_tell` naming
    them with the library's look-alikes (among them chosen exact aliases: a mount tilt carrying the rocking's ax0);
    without one it is `unexplained` (out-of-library motions with that rest value fit the same:
    station.gap.identifiability.seen_only_at_rest), never `explained`."""
    why = _rest_only_text(rest_only)
    if len(named) > len(effects) or _aliases_chosen(effects):
        text = f"cannot tell with this design ({sh}): with {', '.join(effects)}, {why}{alike}{_separating_text(sep)}"
        return Verdict("cannot_tell", [], text, ambiguous=named, separating=sep)
    text = f"not explained by the library: {', '.join(effects)} fit(s) it ({sh}), but {why}"
    return Verdict("unexplained", [], text, partial=effects, remaining=[why])


def _accepted_verdict(
    selection: Selection,
    ident: IdentifiabilityReport,
    sh: str,
    rest_only: dict[str, list[str]],
    heldout_rows: tuple[int, int] | None,
) -> Verdict:
    """The verdict once the chosen effects leave no residual check significant: `explained`, or `cannot_tell`
    naming the effects with every look-alike and alternative model that reproduces them (station.gap.verdict docstring);
    one effect whose parameters the design does not all fix is `explained` with those marked undetermined."""
    effects = selection.effects
    alike = _look_alikes(selection)
    alternatives = [alt for alt in selection.alternatives if set(alt) != set(effects)]  # another model, not the same
    named = _named(effects, alike, alternatives)
    sep = _separating(ident, named, rest_only, alternatives)
    also = _with_look_alikes(effects, alike, alternatives)
    if rest_only:
        return _seen_only_at_rest(effects, rest_only, sh, named, sep, also)
    unpredictable = bool(heldout_rows and heldout_rows[1] < (1.0 - MAX_UNPREDICTABLE) * heldout_rows[0])
    if unpredictable and len(effects) > 1:
        text = (
            f"cannot tell with this design ({sh}): with {', '.join(effects)} {_unpredictable_text(heldout_rows)}"
            f", so no held-out test checks how the gap divides among them; add positions or frequencies{also}"
        )
        return Verdict("cannot_tell", [], text + _separating_text(sep), ambiguous=named, separating=sep)
    if alike or alternatives:
        return _not_told_apart(effects, alike, alternatives, sh, sep)
    return _explained(effects, ident, sh, unpredictable, heldout_rows)


def _unpredictable_text(heldout_rows: tuple[int, int] | None) -> str:
    n_twin, n_model = heldout_rows or (0, 0)
    return (
        f"{n_twin - n_model} of the {n_twin} held-out rows that the twin predicts cannot be predicted (only the "
        "held-out points fix some of the effects' parameters)"
    )


def _too_few_dof(dof: int) -> Verdict:
    """unexplained: the design leaves fewer than MIN_DOF residual degrees of freedom after the calibrated terms,
    so no test of the twin (nor of any effect) can be made."""
    why = (
        f"only {dof} residual degrees of freedom remain after the bias k0 and the calibrated coefficients "
        f"(need >= {MIN_DOF}): nothing can be tested; add positions or frequencies"
    )
    return Verdict("unexplained", [], f"not testable with this design: {why}", remaining=[why])


def _no_gap(noise_before: NoiseCheck) -> Verdict:
    """no_gap, saying which noise reference the residual scatter was checked against."""
    ref = (
        f"; residual scatter consistent with the {noise_before.reference}"
        if noise_before.reference != "none"
        else "; no independent noise reference (no repeats, no noise stated by the session)"
    )
    return Verdict("no_gap", [], "no gap beyond noise: no library effect and no structure test is significant" + ref)


def _left_after_effects(
    selection: Selection,
    dets_after: list[Detector],
    noise_after: NoiseCheck,
    shrink: float | None,
    heldout_after: tuple[float, float] | None,
) -> list[str]:
    """What the chosen effects leave: significant residual checks, further effects beyond the maximum, a held-out
    gap that shrank by less than MIN_SHRINK or stays above HELDOUT_AFTER_SE standard errors."""
    remaining = residual_checks(dets_after, noise_after)
    if selection.capped:
        remaining.append("further library effects still significant beyond the maximum number added")
    if not selection.effects:
        return remaining
    if shrink is not None and shrink < MIN_SHRINK:
        remaining.append(f"held-out gap shrink only {shrink:.2f} (< {MIN_SHRINK})")
    if heldout_after is not None and heldout_after[0] > HELDOUT_AFTER_SE * heldout_after[1]:
        g, se = heldout_after
        remaining.append(f"held-out gap with the effects {g:.3g} = {g / se:.1f} se (> {HELDOUT_AFTER_SE:g} se)")
    return remaining


def _partly_explained(effects: list[str], remaining: list[str]) -> Verdict:
    """unexplained: the effects account for part of the gap, `remaining` names what is left."""
    text = "not explained by the library: " + ", ".join(effects) + " account(s) for part of it, but "
    return Verdict("unexplained", [], text + "; ".join(remaining), partial=effects, remaining=remaining)


def decide(
    dof: int,
    selection: Selection,
    ident: IdentifiabilityReport,
    dets_before: list[Detector],
    dets_after: list[Detector],
    noise_before: NoiseCheck,
    noise_after: NoiseCheck,
    shrink: float | None,
    heldout_after: tuple[float, float] | None = None,
    rest_only: dict[str, list[str]] | None = None,
    heldout_rows: tuple[int, int] | None = None,
) -> Verdict:
    """The verdict; heldout_after = (G, se) of the held-out gap with the chosen effects (station.gap.heldout);
    rest_only: chosen effects' significant parameters seen only at rest, untested by a pulse record;
    heldout_rows: the held-out rows predictable by the twin and by the model with the effects."""
    if dof < MIN_DOF:
        return _too_few_dof(dof)
    effects = selection.effects
    before = residual_checks(dets_before, noise_before)
    rejected = _rejected(selection)  # significant candidates that another test rejects: a gap all the same
    if not effects and not before and not rejected:
        return _no_gap(noise_before)
    remaining = _left_after_effects(selection, dets_after, noise_after, shrink, heldout_after)
    if effects and not remaining:
        sh = f"held-out gap shrink {shrink:.2f}" if shrink is not None else "no held-out gap to shrink"
        return _accepted_verdict(selection, ident, sh, rest_only or {}, heldout_rows)
    if effects:
        return _partly_explained(effects, remaining + rejected)
    before = before + rejected
    return Verdict("unexplained", [], "a gap that no library effect explains: " + "; ".join(before), remaining=before)
