"""The verdict: no gap beyond noise, explained by effect(s) X, not explained, or cannot tell.

Evidence of a gap (before any effect is added), each at level ALPHA with a
Bonferroni correction inside its family:
- a library candidate accepted by the forward selection (station.gap.attribute);
- a structure test on the twin's residuals (station.gap.localise);
- excess scatter: the residual noise of the twin's fit against a reference,
  the pure error of repeats when there are any (lack-of-fit F test), else the
  twin's own noise model (chi-square test); none when neither exists.
"explained": effects were accepted, and after them no structure test and no
excess-scatter test is significant, and the held-out gap shrank by at least
MIN_SHRINK (when there was a held-out gap to shrink). Otherwise "unexplained",
naming what was found and what remains. "cannot_tell": the design leaves fewer
than MIN_DOF residual degrees of freedom after the calibrated terms.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from station.gap.attribute import ALPHA, Selection
from station.gap.localise import Detector

MIN_SHRINK = 0.5
MIN_DOF = 4


@dataclass(frozen=True)
class NoiseCheck:
    reference: str  # "pure error of repeats" | "twin noise model" | "none"
    sigma_ref_radps: float | None
    p_value: float | None

    @property
    def excess(self) -> bool:
        return self.p_value is not None and self.p_value < ALPHA


@dataclass
class Verdict:
    verdict: str
    effects: list[str]
    text: str
    partial: list[str] = field(default_factory=list)
    remaining: list[str] = field(default_factory=list)


def _significant(dets: list[Detector]) -> list[Detector]:
    return [d for d in dets if d.p_value < ALPHA / max(len(dets), 1)]


def decide(
    dof: int,
    selection: Selection,
    dets_before: list[Detector],
    dets_after: list[Detector],
    noise_before: NoiseCheck,
    noise_after: NoiseCheck,
    shrink: float | None,
    more_significant: bool,
) -> Verdict:
    if dof < MIN_DOF:
        return Verdict(
            "cannot_tell",
            [],
            f"cannot tell with this design: only {dof} residual degrees of freedom "
            f"remain after the static levels and the calibrated coefficients (need >= {MIN_DOF}); "
            "add positions or frequencies",
        )
    effects = [s.name for s in selection.chosen]
    sig_before = _significant(dets_before)
    if not effects and not sig_before and not noise_before.excess:
        ref = (
            f"; residual scatter consistent with the {noise_before.reference}"
            if noise_before.reference != "none"
            else "; no independent noise reference (no repeats, no twin noise model)"
        )
        return Verdict(
            "no_gap", [], "no gap beyond noise: no library effect and no structure test is significant" + ref
        )
    remaining = [f"{d.name} (F = {d.F:.1f}, p = {d.p_value:.1e})" for d in _significant(dets_after)]
    if noise_after.excess:
        remaining.append(f"excess scatter against the {noise_after.reference} (p = {noise_after.p_value:.1e})")
    if more_significant:
        remaining.append("further library effects still significant beyond the maximum number added")
    if effects and not remaining and (shrink is None or shrink >= MIN_SHRINK):
        amb = f"; not separable in this design from {', '.join(selection.ambiguous)}" if selection.ambiguous else ""
        sh = f"held-out gap shrink {shrink:.2f}" if shrink is not None else "no held-out gap to shrink"
        return Verdict("explained", effects, f"explained by {', '.join(effects)} ({sh}){amb}")
    if effects:
        why = list(remaining)
        if shrink is not None and shrink < MIN_SHRINK:
            why.append(f"held-out gap shrink only {shrink:.2f} (< {MIN_SHRINK})")
        return Verdict(
            "unexplained",
            [],
            "not explained by the library: " + ", ".join(effects) + " account(s) for part of it, but " + "; ".join(why),
            partial=effects,
            remaining=why,
        )
    why = [f"{d.name} (F = {d.F:.1f}, p = {d.p_value:.1e})" for d in sig_before]
    if noise_before.excess:
        why.append(f"excess scatter against the {noise_before.reference} (p = {noise_before.p_value:.1e})")
    return Verdict("unexplained", [], "a gap that no library effect explains: " + "; ".join(why), remaining=why)
