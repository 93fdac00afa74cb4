"""Sim-to-real gap diagnosis of a recorded session against a twin: `diagnose` and `station gap`.

    station gap SESSION_DIR [--twin CONFIG] --json OUT.json [--html OUT.html] [--twin-out OUT.toml]
    station gap UID --db STORE.sqlite ...          (a session of our own store)

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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from station.analysis.least_squares import FitError
from station.gap import candidates as cl
from station.gap.attribute import ALPHA, MAX_EFFECTS, Scored, Selection, forward_select
from station.gap.design import GapInputError, PointDesign, check_geometry
from station.gap.fit import Channels, Linearisation, ModelFit, evaluate, fit_model
from station.gap.forward import CALIBRATED
from station.gap.heldout import Folds, HeldOut, heldout, shrink
from station.gap.identifiability import IdentifiabilityReport, assess
from station.gap.localise import detectors, maps, standardised, where_text
from station.gap.noise import (
    excess_scatter_pvalue,
    pure_error,
    rate_weights,
    timing_noise,
    timing_rate_sd_radps,
)
from station.gap.rawstreams import raw_evidence
from station.gap.verdict import MIN_DOF, NoiseCheck, Verdict, decide
from station.session import Session
from station.twin.config import TwinConfig, TwinConfigError, default_twin

FORMAT = "piga-gap/1"
PURE_ERROR_MIN_DOF = 5


@dataclass
class GapReport:
    """Everything the diagnosis found; `to_json` is the OUT.json document."""

    verdict: Verdict
    candidates: list[dict]
    gap_before: HeldOut
    gap_after: HeldOut
    where: dict
    identifiability: IdentifiabilityReport
    noise: dict
    coefficients: dict
    twin_out: TwinConfig
    session_info: dict
    elapsed_s: float
    z_before: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    z_after: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    design: PointDesign | None = field(repr=False, default=None)
    tau_z_before: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    raw: dict = field(default_factory=dict)

    @property
    def effects(self) -> list[str]:
        return list(self.verdict.effects)

    def to_json(self) -> dict:
        return {
            "format": FORMAT,
            "verdict": self.verdict.verdict,
            "verdict_text": self.verdict.text,
            "effects": self.verdict.effects,
            "partial_effects": self.verdict.partial,
            "remaining": self.verdict.remaining,
            "candidates": self.candidates,
            "gap_before": self.gap_before.to_json(),
            "gap_after": self.gap_after.to_json(),
            "where": self.where,
            "identifiability": self.identifiability.to_json(),
            "noise": self.noise,
            "calibrated_coefficients": self.coefficients,
            "twin_config": self.twin_out.to_dict(),
            "session": self.session_info,
            "settings": {"alpha": ALPHA, "max_effects": MAX_EFFECTS, "min_dof": MIN_DOF},
            "elapsed_s": self.elapsed_s,
        }


def _noise_check(fit: ModelFit, pe, twin: TwinConfig) -> NoiseCheck:
    if pe is not None and pe.dof >= 3 and fit.dof_rate > pe.dof:
        from scipy import stats

        ss_pe = pe.sigma0_radps**2 * pe.dof
        lof = max(fit.rss_rate - ss_pe, 0.0) / (fit.dof_rate - pe.dof)
        F = lof / max(pe.sigma0_radps**2, 1e-300)
        return NoiseCheck("pure error of repeats", pe.sigma0_radps, float(stats.f.sf(F, fit.dof_rate - pe.dof, pe.dof)))
    if twin.noise.rate_noise_radps > 0:
        p = excess_scatter_pvalue(fit.sigma0_hat_radps, fit.dof_rate, twin.noise.rate_noise_radps)
        return NoiseCheck("twin noise model", twin.noise.rate_noise_radps, p)
    return NoiseCheck("none", None, None)


def _coef_json(fit: ModelFit) -> dict:
    return {c: {"value": float(v), "sigma": float(s)} for c, v, s in zip(CALIBRATED, fit.K, fit.K_sigmas, strict=True)}


def _candidate_entry(
    s: Scored | None, name: str, ident: IdentifiabilityReport, chosen: set[str], final: ModelFit, twin: TwinConfig
) -> dict:
    cid = ident.candidates[name]
    cand = cl.LIBRARY[name]
    entry: dict = {
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
        "accepted": name in chosen,
    }
    if s is None:
        entry.update({"parameters": {}, "uncertainty": {}, "evidence": None, "heldout_shrink": None, "rank": None})
        return entry
    fit = final if name in chosen and name in final.effects else s.fit
    params = {fp.param: float(v) for fp, v in zip(fit.free, fit.values, strict=True) if fp.effect == name}
    unc = {fp.param: float(v) for fp, v in zip(fit.free, fit.sigmas, strict=True) if fp.effect == name}
    entry.update(
        {
            "parameters": params,
            "uncertainty": unc,
            "units": {fp.param: fp.unit for fp in cand.free},
            "evidence": {
                "delta_bic": float(s.dbic),
                "F_rate": None if not math.isfinite(s.F) else float(s.F),
                "p_value": float(s.p_value),
                "delta_rss_in_sigma2": float(s.drss_sigma2),
                "delta_chi2_timing": float(s.dchi2_tau),
                "heldout_gap": None if not math.isfinite(s.heldout_G) else float(s.heldout_G),
            },
            "heldout_shrink": s.heldout_shrink,
        }
    )
    return entry


def diagnose(
    session: Session,
    twin: TwinConfig,
    *,
    exclude: Sequence[str] = (),
    max_effects: int = MAX_EFFECTS,
    suggest: bool = True,
) -> GapReport:
    """Diagnose the gap between a recorded session and the twin (issue 3). Raises GapInputError."""
    t_start = time.perf_counter()
    check_geometry(session, twin)
    design = PointDesign.from_session(session)
    n_pos = design.positions_deg.size
    n_lin = n_pos + len(CALIBRATED)
    if not design.vib.any():
        raise GapInputError("the session has no vibration points: the calibrated coefficients need vibration")
    if design.n_points <= n_lin:
        raise GapInputError(
            f"too few points to fit: {design.n_points} points cannot fit {n_pos} static levels and "
            f"{len(CALIBRATED)} calibrated coefficients"
        )
    lib = cl.library(exclude=exclude)
    tn = timing_noise(design, twin)
    weights = rate_weights(design, twin)
    try:
        probe = evaluate(Channels(design, twin, weights, 1.0, tn.sigma_tau_s), twin)
    except FitError as exc:
        raise GapInputError(f"the design cannot fit the calibrated coefficients: {exc}") from None
    rss = float(np.sum(weights * probe.lin.residuals**2))
    dof0 = design.n_points - n_lin
    sigma_w = math.sqrt(rss / dof0) if rss > 0 else 0.0
    sigma_w = max(sigma_w, 1e-12 * float(np.max(np.abs(design.rate_radps))), 1e-300)
    ch = Channels(design, twin, weights, sigma_w, tn.sigma_tau_s)
    lin = Linearisation(ch, lib)
    base = fit_model(lin, [])
    ident = assess(lin, 1.0, suggest=suggest and dof0 >= MIN_DOF)
    drop = ident.dropped
    start = {"frequency_error.eps_f": tn.eps_f_hat}
    if dof0 >= MIN_DOF:
        selection = forward_select(lin, base, ident.fittable(), drop, start, max_effects)
    else:
        selection = Selection([], [], base, [])
    final = selection.final
    pe = pure_error(design, final.rate_resid_radps, weights)
    pe_ok = pe if (pe is not None and pe.dof >= PURE_ERROR_MIN_DOF) else None
    sigma0 = pe_ok.sigma0_radps if pe_ok else final.sigma0_hat_radps
    if not math.isfinite(sigma0) or sigma0 <= 0:
        sigma0 = sigma_w
    kappa = sigma0 / sigma_w
    ident.noise_ratio = 1.0 / kappa
    for c in ident.candidates.values():
        for p in c.params:
            p.snr_at_scale /= kappa
            p.min_detectable *= kappa
            for s in p.separating:
                if "snr_after_projection_at_typical_magnitude" in s:
                    s["snr_after_projection_at_typical_magnitude"] /= kappa
    folds = Folds.of(design)

    def ho(fit: ModelFit) -> HeldOut:
        return heldout(fit.J, fit.r_white, design, folds, kappa, sigma0, tn.sigma_tau_s)

    h_base = ho(base)
    h_final = ho(final) if selection.chosen else h_base
    first_step = selection.steps[0] if selection.steps else []
    for s in first_step:
        hs = ho(s.fit)
        s.heldout_G = hs.G
        s.heldout_shrink = shrink(h_base, hs)
    total_shrink = shrink(h_base, h_final)
    dets_before = detectors(ch, base)
    dets_after = detectors(ch, final) if selection.chosen else dets_before
    nc_before = _noise_check(base, pe, twin)
    nc_after = _noise_check(final, pe, twin) if selection.chosen else nc_before
    more = False
    if len(selection.chosen) == max_effects and len(selection.steps) > max_effects - 1:
        more = False  # the selection stops at the cap; test one more step
        rest = [n for n in ident.fittable() if n not in {s.name for s in selection.chosen}]
        if rest:
            extra = forward_select(lin, final, rest, drop, start, 1)
            more = bool(extra.chosen)
    verdict = decide(dof0, selection, dets_before, dets_after, nc_before, nc_after, total_shrink, more)
    # Standardised residuals and maps (twin as it is, and after the chosen effects).
    z_before = standardised(base, ch, kappa)
    z_after = standardised(final, ch, kappa)
    tau_z = base.tau_resid_s / tn.sigma_tau_s
    m = maps(design, z_before, tau_z)
    where = {
        "summary": where_text(m, dets_before, ALPHA),
        "after_effects": where_text(maps(design, z_after, final.tau_resid_s / tn.sigma_tau_s), dets_after, ALPHA)
        if selection.chosen
        else None,
        "maps": m,
        "structure_tests_before": [d.to_json() for d in dets_before],
        "structure_tests_after": [d.to_json() for d in dets_after],
    }
    raw = raw_evidence(session, design, twin)
    if raw:
        where["raw_streams"] = raw
    chosen = {s.name for s in selection.chosen}
    scored = {s.name: s for s in first_step}
    for s in selection.chosen:
        scored.setdefault(s.name, s)
    order = [s.name for s in selection.chosen] + [s.name for s in first_step if s.name not in chosen]
    order += [n for n in ident.candidates if n not in order]
    cands = []
    for rank, name in enumerate(order, start=1):
        e = _candidate_entry(scored.get(name), name, ident, chosen, final, twin)
        if e["evidence"] is not None:
            e["rank"] = rank
        cands.append(e)
    twin_out = final.cfg if verdict.verdict == "explained" else twin
    noise = {
        "model": "sigma_i = sigma0 sqrt(T_ref / Tm_i) (white rate noise); timing stamps add "
        "|wbar| sqrt(2) sd_stamp / Tm",
        "T_ref_s": twin.noise.rate_noise_ref_s,
        "sigma0_radps": sigma0,
        "source": "pure error of repeats" if pe_ok else "residual dof of the final model",
        "sigma0_twin_fit_radps": base.sigma0_hat_radps,
        "sigma0_final_fit_radps": final.sigma0_hat_radps,
        "dof_final": final.dof_rate,
        "pure_error": None if pe is None else {"sigma0_radps": pe.sigma0_radps, "dof": pe.dof, "groups": pe.groups},
        "twin_nominal_sigma0_radps": twin.noise.rate_noise_radps,
        "excess_scatter_before": {"reference": nc_before.reference, "p_value": nc_before.p_value},
        "excess_scatter_after": {"reference": nc_after.reference, "p_value": nc_after.p_value},
        "timing": {
            "sigma_tau_s": tn.sigma_tau_s,
            "dof": tn.dof,
            "floor_s": tn.floor_s,
            "max_rate_sd_from_timing_radps": float(np.max(timing_rate_sd_radps(design, twin))),
        },
    }
    info = {
        "n_points": design.n_points,
        "n_vibration": int(design.vib.sum()),
        "positions_deg": [float(p) for p in design.positions_deg],
        "frequencies_hz": [float(f) for f in np.unique(design.freq_hz[design.vib])],
        "raw_streams": len(session.raw),
        "residual_dof": dof0,
    }
    report = GapReport(
        verdict=verdict,
        candidates=cands,
        gap_before=h_base,
        gap_after=h_final,
        where=where,
        identifiability=ident,
        noise=noise,
        coefficients={"twin_refit": _coef_json(base), "with_effects": _coef_json(final)},
        twin_out=twin_out,
        session_info=info,
        elapsed_s=time.perf_counter() - t_start,
        z_before=z_before,
        z_after=z_after,
        design=design,
        tau_z_before=tau_z,
        raw=raw,
    )
    return report


# ----------------------------------------------------------------------------- command line


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="station gap", description="Sim-to-real gap diagnosis of a recorded session.")
    p.add_argument("session", metavar="SESSION_DIR", help="a piga-session/1 directory (or a session uid with --db)")
    p.add_argument("--db", help="read session UID from this SQLite store instead of a directory")
    p.add_argument("--twin", help="twin configuration TOML to compare with (default: the embedded default twin)")
    p.add_argument("--json", required=True, metavar="OUT.json", help="write the diagnosis here")
    p.add_argument("--html", metavar="OUT.html", help="also write a self-contained HTML report")
    p.add_argument("--twin-out", metavar="OUT.toml", help="write the twin with the chosen effect(s) switched on")
    p.add_argument(
        "--exclude",
        action="append",
        default=[],
        metavar="EFFECT",
        help="leave an effect out of the candidate library (repeatable)",
    )
    p.add_argument("--max-effects", type=int, default=MAX_EFFECTS)
    p.add_argument("--no-suggest", action="store_true", help="skip the search for separating test points")
    return p


def _load_session(args: argparse.Namespace) -> Session:
    if args.db:
        from station.store import SessionStore

        with SessionStore(args.db) as store:
            return store.load_session(args.session)
    from station.interchange import read_session

    return read_session(args.session)


def main(argv: list[str] | None = None) -> int:
    """`station gap`: 0 on success (whatever the verdict), 2 on bad input."""
    args = build_parser().parse_args(argv)
    from station.interchange import SessionFormatError

    try:
        twin = TwinConfig.from_toml(args.twin) if args.twin else default_twin()
        session = _load_session(args)
        report = diagnose(
            session, twin, exclude=args.exclude, max_effects=args.max_effects, suggest=not args.no_suggest
        )
    except (GapInputError, SessionFormatError, TwinConfigError, ValueError, FileNotFoundError) as exc:
        print(f"station gap: error: {exc}", file=sys.stderr)
        return 2
    Path(args.json).write_text(json.dumps(clean_json(report.to_json()), indent=2, allow_nan=False))
    if args.html:
        from station.gap.report_html import render

        Path(args.html).write_text(render(report))
    if args.twin_out:
        Path(args.twin_out).write_text(report.twin_out.to_toml())
    print(f"verdict: {report.verdict.verdict}: {report.verdict.text}")
    print(
        f"gap before {report.gap_before.G:.3g}, after {report.gap_after.G:.3g} (held-out mean z^2 - 1); "
        f"{report.elapsed_s:.1f} s"
    )
    return 0


def clean_json(o):
    """Plain JSON values: numpy scalars and arrays converted, NaN and inf as null."""
    if isinstance(o, dict):
        return {str(k): clean_json(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [clean_json(v) for v in o]
    if isinstance(o, np.ndarray):
        return clean_json(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


if __name__ == "__main__":
    sys.exit(main())
