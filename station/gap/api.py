"""Sim-to-real gap diagnosis of a recorded session against a twin: `diagnose` and `station gap`.

    station gap SESSION_DIR [--twin CONFIG] [--json OUT.json] [--html OUT.html] [--twin-out OUT.toml]
    station gap --db STORE.sqlite UID --json OUT.json ...      (a session of our own store)

Python API (stable; the web panel uses it):
    report = diagnose(session, twin)          # GapReport; raises GapInputError on bad input
    report.to_json()                          # the OUT.json document (plain JSON types)
    station.gap.report.render(report)    # the self-contained HTML report
    report.twin_out                           # the twin with the effect(s) switched on

Steps (issue 3): localise (refit the calibrated coefficients, standardised
residuals with honest noise, maps), attribute (identifiability, then every
candidate fitted with the calibrated coefficients and ranked), shrink
(held-out gap before and after), verdict, report (JSON, HTML, twin config).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np
from threadpoolctl import threadpool_limits

from station.gap import candidates as cl
from station.gap.attribute import ALPHA, AMBIGUOUS_DBIC, MAX_EFFECTS, Scored, Selection, forward_select
from station.gap.design import GapInputError, PointDesign, check_geometry
from station.gap.fit import Channels, Linearisation, ModelFit, evaluate, fit_model
from station.gap.forward import CALIBRATED, predict
from station.gap.heldout import Folds, HeldOut, heldout, shrink
from station.gap.identifiability import IdentifiabilityReport, assess, seen_only_at_rest
from station.gap.localise import Detector, detectors, maps, significant, standardised, where_text
from station.gap.noise import (
    HonestNoise,
    PureError,
    StatedNoise,
    TimingNoise,
    excess_scatter_pvalue,
    honest_noise,
    lack_of_fit_pvalue,
    pure_error,
    rate_weights,
    timing_noise,
    timing_rate_sd_radps,
)
from station.gap.rawstreams import GratingRecord, PulseRecord, raw_evidence, raw_summary_text
from station.gap.report import GapReport, render, summary_text
from station.gap.subsets import best_subset
from station.gap.verdict import MIN_DOF, MIN_SHRINK, NoiseCheck, Verdict, decide, family_level
from station.least_squares import FitError
from station.noise_form import form_fits, most_likely
from station.session import Session
from station.twin.config import TwinConfig, TwinConfigError, default_twin

# ----------------------------------------------------------------------------- the diagnosis


def _check_fittable(design: PointDesign) -> None:
    n_lev = design.n_levels
    if not design.vib.any():
        raise GapInputError("the session has no vibration points: the calibrated coefficients need vibration")
    if design.n_points <= n_lev + len(CALIBRATED):
        raise GapInputError(
            f"too few points to fit: {design.n_points} points cannot fit the bias k0 and "
            f"{len(CALIBRATED)} calibrated coefficients ({', '.join(CALIBRATED)})"
        )


def _rate_form(design: PointDesign, twin: TwinConfig, model: TwinConfig | None = None) -> float:
    """Constant fraction f of the rate variance (station.noise_form, shared with identification) by the profile
    likelihood of the model refitted (the twin's own, or the twin with the chosen effects: a strong gap in the
    residuals biases the form)."""
    pred = predict(design, model or twin)
    y = design.rate_radps - pred.base_radps
    try:
        ref_s = twin.noise.rate_noise_ref_s
        fits = form_fits(y, design.level_index, pred.units_radps, CALIBRATED, design.Tm_s, ref_s)
    except FitError as exc:
        raise GapInputError(f"the design cannot fit the calibrated coefficients: {exc}") from None
    return most_likely(fits)


def _channels(
    design: PointDesign,
    twin: TwinConfig,
    tn: TimingNoise,
    stated: StatedNoise,
    grating: GratingRecord | None,
    model: TwinConfig | None = None,
) -> Channels:
    """Observations whitened by their noise: the stated noise where the session states it, else estimated
    (the rate variance's form by likelihood, its level by the scatter of the model refitted, the twin's own
    unless `model` is given; timing first)."""
    if stated.repeatability_radps is not None:
        sigma_w = stated.repeatability_radps
        weights = rate_weights(design, twin, tn.sigma_tau_s, sigma_w, constant_fraction=1.0)
        return Channels(design, twin, weights, sigma_w, tn.sigma_tau_s, grating, 1.0, True, tn.stated)
    f = _rate_form(design, twin, model)
    weights = rate_weights(design, twin, constant_fraction=f)
    try:
        probe = evaluate(Channels(design, twin, weights, 1.0, tn.sigma_tau_s, None, f), model or twin)
    except FitError as exc:
        raise GapInputError(f"the design cannot fit the calibrated coefficients: {exc}") from None
    rss = float(np.sum(weights * probe.lin.residuals**2))
    floor = 1e-12 * float(np.max(np.abs(design.rate_radps)))
    sigma_w = max(math.sqrt(rss / probe.lin.dof), floor, 1e-300)
    # The timing term of the weights needs sigma0: the probe's is close enough (it is a small term).
    weights = rate_weights(design, twin, tn.sigma_tau_s, sigma_w, constant_fraction=f)
    return Channels(design, twin, weights, sigma_w, tn.sigma_tau_s, grating, f, False, tn.stated)


def _noise_check(fit: ModelFit, pe: PureError | None, ch: Channels) -> NoiseCheck:
    """Residual scatter of a fit against an independent reference: the stated repeatability, else repeats."""
    if ch.rate_sigma_known:
        p = excess_scatter_pvalue(fit.sigma0_hat_radps, fit.dof_rate, ch.sigma0_radps)
        return NoiseCheck("stated instrument repeatability", ch.sigma0_radps, p)
    if pe is not None and pe.dof >= 3 and fit.dof_rate > pe.dof:
        return NoiseCheck("pure error of repeats", pe.sigma0_radps, lack_of_fit_pvalue(fit.rss_rate, fit.dof_rate, pe))
    return NoiseCheck("none", None, None)


def _coefficients(fit: ModelFit) -> dict:
    return {c: {"value": float(v), "sigma": float(s)} for c, v, s in zip(CALIBRATED, fit.K, fit.K_sigmas, strict=True)}


# How a lateral resonance's fr and Q are set (station.gap.attribute.lateral_profile, lateral_pulse_profile).
PROFILE_METHOD = (
    "set by profile: a grid (fr 0.5-100 Hz in 41 log steps, Q 0.7-50), then a fine one "
    "around its best point: the point whose kx column removes the most chi^2 (lateral_profile); "
    "where the pulse record rejects it, the point of the rates' region (chi^2 within the 2-dof "
    "test at ALPHA of the best) whose fit the pulse test accepts best (lateral_pulse_profile)"
)


def _table_order(selection: Selection, first: dict[str, Scored], ident: IdentifiabilityReport) -> list[str]:
    """The chosen effects first, then the identifiable candidates of the first step by BIC, then the other scored
    ones, then the unscored."""
    chosen = selection.effects
    order = chosen + [n for n in first if n not in chosen and ident.candidates[n].identifiable]
    order += [n for n in first if n not in order]
    return order + [n for n in ident.candidates if n not in order]


def _identification(name: str, ident: IdentifiabilityReport, twin: TwinConfig, accepted: bool) -> dict:
    """A candidate's entry before its fit: cause, identifiability, fixed parameters, units and bounds."""
    cid, cand = ident.candidates[name], cl.LIBRARY[name]
    return {
        "name": name,
        "cause": cand.cause,
        "identifiable": cid.identifiable,
        "identifiability": {
            "reason": cid.reason,
            "fitted_parameters": cid.kept,
            "collinear_with": [{"candidate": n, "cos": round(c, 4)} for n, c in cid.collinear_with],
        },
        "fixed_parameters": cl.fixed_params(cand, twin),
        "notes": cand.notes,
        "explanation": cand.effect.explanation,
        "separating": cand.effect.separating,
        "accepted": accepted,
        "rank": None,
        "parameters": {},
        "uncertainty": {},
        "units": {fp.param: fp.unit for fp in cand.free},
        "plausible_bounds": {fp.param: fp.bound for fp in cand.free},
        "evidence": None,
        "heldout_shrink": None,
    }


def _evidence(s: Scored, heldout_gap: float, heldout_rank: int | None) -> dict:
    """A scored candidate's evidence: BIC, F, p, the channels' chi^2, the held-out gap with it, rivals, rejections."""
    return {
        "delta_bic": s.dbic,
        "F_rate": s.F,
        "p_value": s.p_value,
        "delta_rss_in_sigma2": s.drss_sigma2,
        "delta_chi2_timing": s.dchi2_tau,
        "heldout_gap_with_it": heldout_gap,
        "heldout_rank": heldout_rank,
        "rivals_reproducing_it": s.rivals,
        "beyond_bounds": s.beyond_bounds,
        "rejected_by": s.rejected_by or None,
        "fit_converged": s.fit.converged,
    }


def _place(name: str, ranked: list[str]) -> int | None:
    """1-based place of `name` in `ranked`, None if it is not ranked."""
    return ranked.index(name) + 1 if name in ranked else None


def _fitted(
    s: Scored, fit: ModelFit, gap_and_shrink: tuple[float, float | None], rank: int | None, heldout_rank: int | None
) -> dict:
    """A scored candidate's fields of the table: its rank, its parameters as `fit` has them, the held-out gap
    with it and its shrink, the evidence, and how set parameters were profiled."""
    parameters, uncertainty = fit.effect_parameters(s.name)
    G, shrunk = gap_and_shrink
    out: dict = {"rank": rank, "parameters": parameters, "uncertainty": uncertainty, "heldout_shrink": shrunk}
    out["evidence"] = _evidence(s, G, heldout_rank)
    if s.profiled:
        out["profiled_parameters"] = {**s.profiled, "method": PROFILE_METHOD}
    return out


def _candidate_table(
    selection: Selection,
    ident: IdentifiabilityReport,
    shrinks: dict[str, tuple[float, float | None]],
    twin: TwinConfig,
) -> list[dict]:
    """Every candidate: the chosen effects first, then the identifiable ones by BIC, then the rest.

    Only identifiable candidates are ranked ("rank", by BIC; "heldout_rank", by the held-out gap
    with the candidate alone): the others are reported with their fits but not ranked.
    """
    first = {s.name: s for s in selection.steps[0]} if selection.steps else {}
    chosen = {s.name: s for s in selection.chosen}
    scored = {**first, **chosen}
    order = _table_order(selection, first, ident)
    ranked = [n for n in order if n in scored and ident.candidates[n].identifiable]
    by_heldout = sorted(
        [n for n in shrinks if ident.candidates[n].identifiable], key=lambda n: np.nan_to_num(shrinks[n][0], nan=np.inf)
    )
    table = []
    for name in order:
        entry = _identification(name, ident, twin, name in chosen)
        if name in scored:
            # A chosen effect's parameters come from the final joint fit.
            fit = selection.final if name in chosen else scored[name].fit
            gap_and_shrink = shrinks.get(name, (math.nan, None))
            entry |= _fitted(scored[name], fit, gap_and_shrink, _place(name, ranked), _place(name, by_heldout))
        table.append(entry)
    return table


def _noise_json(
    form_from: str,
    twin: TwinConfig,
    honest: HonestNoise,
    base: ModelFit,
    final: ModelFit,
    pe: PureError | None,
    checks: tuple[NoiseCheck, NoiseCheck],
    tn: TimingNoise,
    design: PointDesign,
    ch: Channels,
    stated: StatedNoise,
) -> dict:
    return {
        "model": "var(wbar_i) = sigma0^2 (f + (1 - f) T_ref / Tm_i) (f: a per-window repeatability; 1 - f: white "
        "rate noise over the window) + (|wbar_i| sigma_tau / Tm_i)^2 (the two time stamps of Tm)",
        "constant_fraction_f": ch.constant_fraction,
        "constant_fraction_chosen_on": form_from,
        "stated_by_session": stated.to_json(),
        "rate_noise_known": ch.rate_sigma_known,
        "timing_noise_known": ch.tau_sigma_known,
        "static_model": "one bias k0 for the whole session; every position's static rate is the twin's "
        "k0 + kz c + kzz c^2 + ky (1 - c^2) + k3 c^3 - earth rate (no free per-position level)",
        "T_ref_s": twin.noise.rate_noise_ref_s,
        "sigma0_radps": honest.sigma0_radps,
        "sigma0_dof": honest.dof,
        "source": honest.source,
        "sigma0_twin_fit_radps": base.sigma0_hat_radps,
        "sigma0_final_fit_radps": final.sigma0_hat_radps,
        "pure_error": None if pe is None else {"sigma0_radps": pe.sigma0_radps, "dof": pe.dof, "groups": pe.groups},
        "excess_scatter_before": vars(checks[0]),
        "excess_scatter_after": vars(checks[1]),
        "timing": {
            "sigma_tau_s": tn.sigma_tau_s,
            "dof": tn.dof,
            "floor_s": tn.floor_s,
            "eps_f_from_period_identities": tn.eps_f_hat,
            "max_rate_sd_from_timing_radps": float(np.max(timing_rate_sd_radps(design, tn.sigma_tau_s))),
        },
    }


@dataclass(frozen=True)
class _Observations:
    """What the diagnosis reads from a session: its design, the noise it states, the timing noise (estimated
    first) and the raw records (the grating harmonics, the pulse edges) where it has them."""

    design: PointDesign
    stated: StatedNoise
    tn: TimingNoise
    grating: GratingRecord | None
    pulses: PulseRecord | None

    @classmethod
    def of(cls, session: Session, twin: TwinConfig) -> _Observations:
        """The session's observations; raises GapInputError where its geometry or design cannot be diagnosed."""
        check_geometry(session, twin)
        design = PointDesign.from_session(session)
        _check_fittable(design)
        stated = StatedNoise.from_meta(session.meta)
        tn = timing_noise(design, twin, stated)
        sd_stamp = tn.sigma_tau_s / math.sqrt(2.0)
        grating = GratingRecord.from_session(session, design, sd_stamp, stated.grating_noise_m)
        tick = stated.timer_resolution_s if stated.timer_resolution_s is not None else twin.noise.timer_tick_s
        pulses = PulseRecord.from_session(session, design, twin, sd_stamp, tick) if session.raw else None
        return cls(design, stated, tn, grating, pulses)

    def channels(self, twin: TwinConfig, model: TwinConfig | None = None) -> Channels:
        """The observations whitened by their noise (_channels), with the pulse record."""
        return replace(_channels(self.design, twin, self.tn, self.stated, self.grating, model), pulses=self.pulses)


_Attribution = tuple[ModelFit, IdentifiabilityReport, list[Detector], Selection]


def _attribute(ch: Channels, exclude: Sequence[str], max_effects: int, suggest: bool, has_raw: bool) -> _Attribution:
    """The twin refitted, identifiability, its structure tests and the forward selection, on channels ch."""
    lin = Linearisation(ch, cl.library(exclude=exclude))
    base = fit_model(lin, [])
    ident = assess(lin, suggest=suggest and base.dof_rate >= MIN_DOF, has_raw=has_raw)
    dets = detectors(ch, base)
    if base.dof_rate < MIN_DOF:
        return base, ident, dets, Selection([], [], base)
    # The pulse record rejects a candidate at the level the verdict tests it at (station.gap.verdict.residual_checks).
    pulse_level = family_level(len(dets)) / max(len(dets), 1)
    names, drop = ident.fittable(), ident.dropped
    greedy = forward_select(lin, base, names, drop, max_effects, pulse_level)
    return base, ident, dets, best_subset(lin, base, greedy, names, drop, max_effects, pulse_level)


def _attribution(
    obs: _Observations, twin: TwinConfig, exclude: Sequence[str], max_effects: int, suggest: bool, has_raw: bool
) -> tuple[Channels, _Attribution, str]:
    """The attribution on channels of the twin's rate-noise form; where the model with the chosen effects gives the
    form another value, the attribution again on channels of that form. Also which model the form was chosen on."""
    attribute = partial(_attribute, exclude=exclude, max_effects=max_effects, suggest=suggest, has_raw=has_raw)
    ch = obs.channels(twin)
    found = attribute(ch)
    selection = found[3]
    if selection.chosen and not ch.rate_sigma_known:
        # The rate noise's form again from the model with the effects; where it differs, the attribution again.
        model, first = selection.final.cfg, ", ".join(selection.effects)
        if _rate_form(obs.design, twin, model) != ch.constant_fraction:
            ch = obs.channels(twin, model)
            return ch, attribute(ch), f"the twin with {first} (the effects chosen with the twin's own form)"
    return ch, found, "the twin refitted"


def _honest_noise(ch: Channels, final: ModelFit, pe: PureError | None, dets_after: list[Detector]) -> HonestNoise:
    """The rate noise sigma0: as the session states it, else from the pure error of repeats or the final model's
    residuals less the structure its significant rate tests find (station.gap.noise.honest_noise)."""
    if ch.rate_sigma_known:
        return HonestNoise(ch.sigma0_radps, 0, "stated by the session (instrument_repeatability_radps)")
    structure = [d.basis for d in significant(dets_after, ALPHA) if d.basis is not None and d.channel == "rate"]
    return honest_noise(pe, final.r_white, ch.n_rate, final.dof_rate, ch.sigma0_radps, structure)


def _heldout_gaps(
    obs: _Observations, base: ModelFit, selection: Selection, kappa: float, sigma0_radps: float
) -> tuple[HeldOut, HeldOut, dict[str, tuple[float, float | None]]]:
    """The held-out gap of the twin, of the chosen model, and (gap, shrink) of each first-step candidate alone."""
    folds = Folds.of(obs.design)

    def ho(fit: ModelFit) -> HeldOut:
        g_index = None if obs.grating is None else obs.grating.index
        return heldout(fit.J, fit.r_white, obs.design, folds, kappa, sigma0_radps, obs.tn.sigma_tau_s, g_index)

    h_base = ho(base)
    h_final = ho(selection.final) if selection.chosen else h_base
    shrinks = {}
    for s in selection.steps[0] if selection.steps else []:
        h = ho(s.fit)
        shrinks[s.name] = (h.G, shrink(h_base, h))
    return h_base, h_final, shrinks


class _Residuals(NamedTuple):
    """z of every point and of every period identity, twin refitted and with the chosen effects."""

    z_before: np.ndarray
    z_after: np.ndarray
    tau_z_before: np.ndarray
    tau_z_after: np.ndarray


def _standardised_residuals(
    base: ModelFit, final: ModelFit, chosen: bool, ch: Channels, kappa: float, sigma_tau_s: float
) -> _Residuals:
    """The standardised residuals before and after the chosen effects (the same arrays when none was added)."""
    z_before, tau_z_before = standardised(base, ch, kappa), base.tau_resid_s / sigma_tau_s
    z_after, tau_z_after = z_before, tau_z_before  # the same arrays when no effect was added
    if chosen:
        z_after, tau_z_after = standardised(final, ch, kappa), final.tau_resid_s / sigma_tau_s
    return _Residuals(z_before, z_after, tau_z_before, tau_z_after)


def _verdict(
    attribution: _Attribution,
    dets_after: list[Detector],
    checks: tuple[NoiseCheck, NoiseCheck],
    h_base: HeldOut,
    h_final: HeldOut,
    rest_only: dict[str, list[str]],
) -> Verdict:
    """The verdict (station.gap.verdict.decide) on the attribution, the tests after it and the held-out gaps."""
    base, ident, dets_before, selection = attribution
    heldout_after, heldout_rows = (h_final.G, h_final.se), (h_base.n_rows, h_final.n_rows)
    shrunk = shrink(h_base, h_final)
    return decide(
        base.dof_rate,
        selection,
        ident,
        dets_before,
        dets_after,
        *checks,
        shrunk,
        heldout_after,
        rest_only,
        heldout_rows,
    )


def _where(
    maps_before: dict, maps_after: dict | None, dets_before: list[Detector], dets_after: list[Detector], raw: dict
) -> dict:
    """Where the gap lies: in words before and after the effects, the maps, the structure tests, the raw streams."""
    return {
        "summary": where_text(maps_before, dets_before, family_level(len(dets_before)))
        + (f" {raw_summary_text(raw)}." if raw else ""),
        "after_effects": where_text(maps_after, dets_after, family_level(len(dets_after))) if maps_after else None,
        "maps": maps_before,
        "maps_after_effects": maps_after,
        "structure_tests_before": [d.to_json() for d in dets_before],
        "structure_tests_after": [d.to_json() for d in dets_after],
        "raw_streams": raw or None,
    }


def _session_info(design: PointDesign, session: Session, dof0: int, exclude: Sequence[str]) -> dict:
    """The session's design as diagnosed: points, positions, frequencies, raw streams, residual dof."""
    return {
        "n_points": design.n_points,
        "n_vibration": int(design.vib.sum()),
        "positions_deg": design.positions_deg,
        "frequencies_hz": np.unique(design.freq_hz[design.vib]),
        "raw_streams": len(session.raw),
        "residual_dof": dof0,
        "excluded_from_library": list(exclude),
    }


def _settings(max_effects: int, suggest: bool) -> dict:
    """The diagnosis' thresholds and options, as the report states them."""
    return {
        "alpha": ALPHA,
        "ambiguous_delta_bic": AMBIGUOUS_DBIC,
        "max_effects": max_effects,
        "min_dof": MIN_DOF,
        "min_shrink": MIN_SHRINK,
        "suggest_separating_points": suggest,
    }


# One BLAS thread: the diagnosis's matrices (points x tens of columns) gain no time from more, and their
# spin-waits cost CPU (a 640-point session: 1.5 s of 10, BENCHMARKS.md "Speed"; the 29 cases of the shared
# development set: tests/gap/test_devset.py 128-134 s -> 82 s of CPU, BENCHMARKS.md; the same reports to the bit).
@threadpool_limits.wrap(limits=1)
def diagnose(
    session: Session,
    twin: TwinConfig,
    *,
    exclude: Sequence[str] = (),
    max_effects: int = MAX_EFFECTS,
    suggest: bool = True,
) -> GapReport:
    """Diagnose the gap between a recorded session and the twin (issue 3). Raises GapInputError on bad input.

    exclude: effects left out of the candidate library; suggest=False skips the
    search for separating test points (the slowest part of the identifiability check).
    """
    t_start = time.perf_counter()
    obs = _Observations.of(session, twin)
    design, tn = obs.design, obs.tn
    ch, attribution, form_from = _attribution(obs, twin, exclude, max_effects, suggest, bool(session.raw))
    base, ident, dets_before, selection = attribution
    final = selection.final

    # Localise: the structure tests after the effects, then the honest noise.
    dets_after = detectors(ch, final)
    pe = pure_error(design, final.rate_resid_radps, ch.weights)
    honest = _honest_noise(ch, final, pe, dets_after)
    kappa = honest.sigma0_radps / ch.sigma0_radps
    ident.noise_ratio = 1.0 / kappa

    # Shrink: the held-out gap of the twin, of each candidate alone, and of the chosen model.
    h_base, h_final, shrinks = _heldout_gaps(obs, base, selection, kappa, honest.sigma0_radps)
    checks = (_noise_check(base, pe, ch), _noise_check(final, pe, ch))
    rest_only = seen_only_at_rest(final, ch) if obs.pulses is None else {}
    verdict = _verdict(attribution, dets_after, checks, h_base, h_final, rest_only)

    # Report: standardised residuals, their maps and the raw streams' evidence.
    res = _standardised_residuals(base, final, bool(selection.chosen), ch, kappa, tn.sigma_tau_s)
    raw = raw_evidence(session, design, base.refitted_cfg(), tn.sigma_tau_s / math.sqrt(2.0))
    maps_before = maps(design, res.z_before, res.tau_z_before)
    maps_after = maps(design, res.z_after, res.tau_z_after) if selection.chosen else None
    return GapReport(
        verdict=verdict,
        candidates=_candidate_table(selection, ident, shrinks, twin),
        gap_before=h_base,
        gap_after=h_final,
        where=_where(maps_before, maps_after, dets_before, dets_after, raw),
        identifiability=ident,
        noise=_noise_json(form_from, twin, honest, base, final, pe, checks, tn, design, ch, obs.stated),
        coefficients={"twin_refit": _coefficients(base), "with_effects": _coefficients(final)},
        twin_out=final.cfg if verdict.verdict == "explained" else twin,
        session_info=_session_info(design, session, base.dof_rate, exclude),
        settings=_settings(max_effects, suggest),
        elapsed_s=time.perf_counter() - t_start,
        design=design,
        z_before=res.z_before,
        z_after=res.z_after,
        tau_z_before=res.tau_z_before,
        tau_z_after=res.tau_z_after,
        raw=raw,
    )


# ----------------------------------------------------------------------------- command line


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="station gap", description="Sim-to-real gap diagnosis of a recorded session.")
    p.add_argument("session", metavar="SESSION_DIR", help="a piga-session/1 directory (or a session UID with --db)")
    p.add_argument("--db", metavar="STORE", help="read session UID from this SQLite store instead of a directory")
    p.add_argument("--twin", help="twin configuration TOML to compare with (default: the embedded default twin)")
    p.add_argument("--json", metavar="OUT.json", help="also write the whole diagnosis here (JSON)")
    p.add_argument("--html", metavar="OUT.html", help="also write a self-contained HTML report")
    p.add_argument("--twin-out", metavar="OUT.toml", help="write the twin with the chosen effect(s) switched on")
    p.add_argument(
        "--exclude",
        action="append",
        default=[],
        metavar="EFFECT",
        help="leave an effect out of the candidate library (repeatable)",
    )
    p.add_argument("--max-effects", type=int, default=MAX_EFFECTS,
                   help=f"at most this many effects added to the twin (default {MAX_EFFECTS})")  # fmt: skip
    p.add_argument("--no-suggest", action="store_true", help="skip the search for separating test points")
    return p


def load_session(path_or_uid: str, db: str | None = None) -> Session:
    """A piga-session/1 directory, or session `path_or_uid` of the SQLite store `db`."""
    if db:
        from station.store import SessionStore

        if not Path(db).is_file():
            raise FileNotFoundError(f"no store {db}")
        with SessionStore(db) as store:
            return store.load_session(path_or_uid)
    from station.interchange import read_session

    return read_session(path_or_uid)


def main(argv: list[str] | None = None) -> int:
    """`station gap`: 0 on success (whatever the verdict), 2 on bad input."""
    args = build_parser().parse_args(argv)
    from station.interchange import SessionFormatError
    from station.store import StoreError

    try:
        twin = TwinConfig.from_toml(args.twin) if args.twin else default_twin()
        session = load_session(args.session, args.db)
        report = diagnose(
            session, twin, exclude=args.exclude, max_effects=args.max_effects, suggest=not args.no_suggest
        )
    except (GapInputError, SessionFormatError, TwinConfigError, StoreError, ValueError, FileNotFoundError) as exc:
        print(f"station gap: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        Path(args.json).write_text(json.dumps(report.to_json(), indent=2, allow_nan=False))
    if args.html:
        Path(args.html).write_text(render(report))
    if args.twin_out:
        Path(args.twin_out).write_text(report.twin_out.to_toml())
    print(summary_text(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
