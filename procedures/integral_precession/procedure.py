"""Seed 000: integral precession calibration of a PIGA on the linear vibration table.

- `integral_precession.planning`: det(Q) and RES(n) versus n, uncertainties pre-estimated by
  eqs. 22 and 24, the test time per point and in total (5.1.2-5.1.4). Nothing moves.
- `integral_precession.self_alignment`: the misalignment angle from static windows (eqs. 25-27).
- `integral_precession`: at each indexing position the vibration tests at
  every frequency, then the static test (5.2); identified by the integral method
  (exact window means, eqs. 19-22) and by the integer periodic vibration baseline
  (eq. 35) on the same data; with the measured Zs1(w) (eq. 32) and axs1 (eq. 34)
  compensated when given.
- `integral_precession.integer_periodic_vibration`: the classical baseline, its results first.
- `integral_precession.multi_frequency`: the multi-frequency method at 0, 45 and 180 deg (6.2.3).

The error-source experiments (Tables 5-7) are in procedures/integral_precession/procedure_error_sources.py.
"""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np

from procedures.common.session_certificate import issue_certificate, result_provenance, session_uid
from procedures.integral_precession.alignment import multi_position, two_position
from procedures.integral_precession.budget import identify_with_budget
from procedures.integral_precession.design_check import check_design
from procedures.integral_precession.identify import (
    METHODS,
    Compensation,
    Identification,
    Method,
    state_first_passage_bias,
)
from procedures.integral_precession.planning import design_quality, relative_sensitivity
from procedures.integral_precession.report import certificate, render_report
from station import constants
from station.engine.params import Param
from station.engine.registry import Analysis, procedure
from station.engine.steps import Checkpoint, MeasurePoint, Note
from station.htmlkit import document, esc, svg, table
from station.session import Session, StationInfo
from station.twin.plan import (
    SEED000_FREQS_HZ,
    SEED000_WINDOW_S,
    equal_angle_positions_deg,
    multiposition_plan,
    point_id,
    preset_pulses,
)
from station.twin.regressors import COEFFICIENTS


def _positions(default: list[float], help_: str) -> Param:
    return Param("positions_deg", list, default=default, min=-360.0, max=360.0, unit="deg", help=help_)


COMMON = (
    Param("freqs_hz", list, default=list(SEED000_FREQS_HZ), min=0.1, max=10.0, unit="Hz",
          help="vibration frequencies at every position"),
    Param("window_s", float, default=SEED000_WINDOW_S, min=1.0, max=100_000.0, unit="s",
          help="target window length: the preset is the whole revolutions that take about this long"),
    Param("settle_s", float, default=5.0, min=0.0, max=600.0, unit="s", help="settling after each change"),
    Param("raw", bool, default=False, help="record raw streams (every pulse edge, grating stretch)"),
)  # fmt: skip
COMPENSATION = (
    Param("zs1_z0_m", float, default=0.0, min=-1e-3, max=1e-3, unit="m",
          help="measured Zs1(w) = z0 + z1 w (eq. 32): z0; 0 and 0 leave it uncompensated"),
    Param("zs1_z1_m_s", float, default=0.0, min=-1e-4, max=1e-4, unit="m s/rad", help="measured Zs1(w): z1"),
    Param("axs1_rad", float, default=0.0, min=-1e-3, max=1e-3, unit="rad",
          help="measured parasitic rotation axs1 (eq. 34); 0 leaves it uncompensated"),
    Param("eps_f", float, default=0.0, min=-1e-3, max=1e-3, unit="1",
          help="measured relative frequency error (Table 6): w = w_cmd (1 + eps_f); 0 leaves it uncompensated"),
)  # fmt: skip
# Standard uncertainties of the measured inputs, from the error-source experiments (procedures/integral_precession/
# procedure_error_sources.py); left out, the budget takes them from config/instruments/references.toml.
UNCERTAINTIES = (
    Param("zs1_z0_sigma_m", float, default=None, min=0.0, max=1e-3, unit="m", help="u(z0) of the Zs1 line fit"),
    Param("zs1_z1_sigma_m_s", float, default=None, min=0.0, max=1e-4, unit="m s/rad", help="u(z1) of the line fit"),
    Param("zs1_z0_z1_corr", float, default=0.0, min=-1.0, max=1.0, help="correlation of z0 and z1 of the line fit"),
    Param("axs1_sigma_rad", float, default=None, min=0.0, max=1e-3, unit="rad", help="u(axs1) of the gradiometer"),
    Param("eps_f_sigma", float, default=None, min=0.0, max=1e-3, unit="1", help="u(eps_f) of the stability test"),
)  # fmt: skip


def _compensation(params: dict) -> Compensation | None:
    z0, z1, axs1, eps_f = (float(params.get(k) or 0.0) for k in ("zs1_z0_m", "zs1_z1_m_s", "axs1_rad", "eps_f"))
    if z0 == z1 == axs1 == eps_f == 0.0:
        return None
    return Compensation(zs1_m=(lambda w: z0 + z1 * w) if (z0 or z1) else None, axs1_rad=axs1, eps_f=eps_f)


def _summary(results: dict[str, Identification]) -> str:
    lines = []
    for m, r in results.items():
        if r.budget is not None:
            U, k = r.budget.expanded_uncertainty(), r.budget.coverage_factors()
            coefs = ", ".join(f"{n} = {v:.6e} ± {x:.1e} (U, k = {kk:.2f})"
                              for n, v, x, kk in zip(r.names, r.values, U, k, strict=True))  # fmt: skip
        else:
            coefs = ", ".join(f"{n} = {v:.6e} ± {s:.1e}" for n, v, s in zip(r.names, r.values, r.sigmas, strict=True))
        coefs += "".join(f"; {n}: {r.bias_note(n)}" for n in r.first_passage_bias)
        verdict = "no outlier" if r.reliable else "possible outlier"
        few = r.budget.few_dof() if r.budget is not None else []
        flag = f"; few dof ({r.dof}) for {', '.join(few)}: t-based U" if few else ""
        lines.append(f"{m}: {coefs}; sigma of Y (eq. 21) = {r.sigma_Y_eq21:.3e} rad/s, mu = {r.mu_eq28:.2f} "
                     f"(mu_c = {r.mu_c_eq28:.2f}, eq. 28): {verdict}{flag}")  # fmt: skip
    return "\n".join(lines)


def _analyse(session: Session, order: tuple[Method, ...], title: str) -> Analysis:
    """Identify, budget each identification (GUM), the report, and the certificate of the primary one."""
    params = session.meta.get("params", {})
    results: dict[str, Identification] = {m: identify_with_budget(session, m) for m in order}
    comp = _compensation(params)
    if comp is not None:
        results["integral_compensated"] = identify_with_budget(session, "integral", comp)
    if {"baseline", "integral"} <= set(results):
        state_first_passage_bias(results["baseline"], results["integral"])
    uid = session_uid(session)
    html = render_report(session, results, title=f"Session {uid}: {title}", config=params)
    primary = "integral_compensated" if comp is not None else order[0]
    files, why_not = issue_certificate(lambda: certificate(session, results, primary, procedure_title=title), uid)
    prov = result_provenance(session)
    docs = {m: {**r.to_json(), "provenance": prov} for m, r in results.items()}
    return Analysis(docs, html, "\n".join(filter(None, [_summary(results), why_not])), files)


def analyse_integral(session: Session) -> Analysis:
    """Both identifications (seed 000 eqs. 19-22 and 35), the compensated one if asked, and the report."""
    return _analyse(session, METHODS, "integral precession (seed 000)")


def analyse_baseline(session: Session) -> Analysis:
    return _analyse(session, tuple(reversed(METHODS)), "integer periodic vibration baseline (seed 000 eq. 35)")


def analyse_multi_frequency(session: Session) -> Analysis:
    return _analyse(session, METHODS, "multi-frequency method at 0, 45, 180 deg (seed 000 6.2.3)")


def _multiposition(p: dict):
    plan = multiposition_plan(p["positions_deg"], p["freqs_hz"], p["window_s"])
    yield Note(f"{len(plan)} points at {len(p['positions_deg'])} positions, {p['freqs_hz']} Hz")
    for i, spec in enumerate(plan):
        yield MeasurePoint(point_id(i, spec), spec.position_deg, spec.freq_hz, spec.preset_pulses, p["settle_s"],
                           p["raw"])  # fmt: skip
        if spec.freq_hz == 0:
            yield Checkpoint(f"position {spec.position_deg:g} deg done")


@procedure(
    "integral_precession",
    "Integral precession calibration on the vibration table (seed 000)",
    (
        _positions(equal_angle_positions_deg(10), "indexing positions (seed 000: 10 equal angles)"),
        *COMMON,
        *COMPENSATION,
        *UNCERTAINTIES,
    ),
    analyse=analyse_integral,
    check_design=check_design,
)
def integral_precession(p: dict):
    return (yield from _multiposition(p))


@procedure(
    "integral_precession.integer_periodic_vibration",
    "Integer periodic vibration method, the classical baseline (seed 000 eq. 35, Ref. 22)",
    (_positions(equal_angle_positions_deg(9), "indexing positions (Ref. 22: 9 equal angles)"), *COMMON),
    analyse=analyse_baseline,
    check_design=check_design,
)
def integer_periodic_vibration(p: dict):
    return (yield from _multiposition(p))


@procedure(
    "integral_precession.multi_frequency",
    "Multi-frequency method: up, down and 45 deg (seed 000 6.2.3, Ref. 21)",
    (_positions([0.0, 45.0, 180.0], "indexing positions (0, 45 and 180 deg)"), *COMMON),
    analyse=analyse_multi_frequency,
    check_design=check_design,
)
def multi_frequency(p: dict):
    return (yield from _multiposition(p))


# ---- planning ------------------------------------------------------------------------------------------


def analyse_planning(session: Session) -> Analysis:
    """The planning report of seed 000 5.1: det(Q), RES(n), eq. 22/24 uncertainties, test times."""
    p = session.meta.get("params", {})
    st: StationInfo = session.station
    kw = {"window_s": p["window_s"], "sigma_p_pulses": p["sigma_p_pulses"], "sigma_T_s": p["sigma_T_s"]}
    chosen = design_quality(p["positions_deg"], p["freqs_hz"], st, **kw)
    ns = np.arange(p["n_min"], p["n_max"] + 1)
    det_q = np.array([design_quality(equal_angle_positions_deg(n), p["freqs_hz"], st, **kw).det_Q for n in ns])
    res = relative_sensitivity(det_q)
    by_freq = {f: design_quality(p["positions_deg"], [f], st, **kw).sigma_k for f in p["freqs_hz"]}
    plan = multiposition_plan(p["positions_deg"], p["freqs_hz"], p["window_s"])
    test_s = {f"{s.position_deg:g} deg": t for s, t in zip(plan, chosen.window_s, strict=True) if s.freq_hz == 0}
    total_s = float(np.sum(chosen.window_s))
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.6))
    ax[0].semilogy(ns, det_q, "o-")
    ax[0].set(title="det(Q) vs equal-angle positions n (Fig. 6)", xlabel="n")
    ax[1].plot(ns, res, "o-")
    ax[1].set(title="RES(n), eq. 23 (Fig. 7)", xlabel="n")
    for a in ax:
        a.grid(alpha=0.3)
    rows = [(f"{f:g} Hz", *(f"{v:.2e}" for v in s)) for f, s in by_freq.items()]
    rows.append(("all", *(f"{v:.2e}" for v in chosen.sigma_k)))
    parts = [
        f"<p>Design: {len(p['positions_deg'])} positions {esc(p['positions_deg'])} at {esc(p['freqs_hz'])} Hz; "
        f"window {p['window_s']:g} s; eq. 24 rate uncertainty {chosen.sigma_rate_radps:.3e} rad/s "
        f"(sigma_P = {p['sigma_p_pulses']:g} pulse, sigma_T = {p['sigma_T_s']:g} s); det(Q) = {chosen.det_Q:.3e}.</p>",
        "<h2>Pre-estimated uncertainties (eq. 22)</h2>",
        table(("frequencies", *(f"σ {c}" for c in COEFFICIENTS)), rows),
        "<h2>D-optimality and sensitivity</h2>" + svg(fig),
        "<h2>Test time per point</h2>",
        table(("position", "window Tm (s)"), ((k, f"{v:.1f}") for k, v in test_s.items())),
        f"<p>Total window time {total_s / 3600:.2f} h (each vibration point at a position lasts about as "
        f"long as its static point; moves, ramps and settling come on top: see the dry run).</p>",
    ]
    results = {
        "planning": {
            "positions_deg": p["positions_deg"],
            "freqs_hz": p["freqs_hz"],
            "sigma_rate_radps": chosen.sigma_rate_radps,
            "det_Q": chosen.det_Q,
            "sigma_k": dict(zip(COEFFICIENTS, map(float, chosen.sigma_k), strict=True)),
            "sigma_k_by_frequency": {
                str(f): dict(zip(COEFFICIENTS, map(float, s), strict=True)) for f, s in by_freq.items()
            },
            "n": ns.tolist(),
            "det_Q_vs_n": det_q.tolist(),
            "RES_vs_n": [None if math.isnan(r) else float(r) for r in res],
            "window_s_by_position": test_s,
            "total_window_s": total_s,
        }
    }
    planned = ", ".join(f"{c} {v:.2e}" for c, v in zip(COEFFICIENTS, chosen.sigma_k, strict=True))
    summary = f"planned sigma_k: {planned}; {total_s / 3600:.2f} h of windows"
    return Analysis(results, document("Planning of a seed-000 session (5.1)", parts), summary)


@procedure(
    "integral_precession.planning",
    "Planning: det(Q), RES(n), uncertainty pre-estimation and test time (seed 000 5.1); nothing moves",
    (
        _positions(equal_angle_positions_deg(10), "indexing positions of the design to evaluate"),
        *COMMON[:2],
        Param("sigma_p_pulses", float, default=1.0, min=0.0, max=100.0, unit="pulse", help="counting uncertainty"),
        Param("sigma_T_s", float, default=1e-6, min=0.0, max=1e-2, unit="s", help="timing uncertainty (eq. 24)"),
        Param("n_min", int, default=4, min=3, max=100, help="smallest n of the det(Q), RES(n) curves"),
        Param("n_max", int, default=40, min=4, max=100, help="largest n of the det(Q), RES(n) curves"),
    ),
    analyse=analyse_planning,
    check_design=check_design,
)
def planning(p: dict):
    yield Note(f"planning {len(p['positions_deg'])} positions at {p['freqs_hz']} Hz; nothing moves")


# ---- self-alignment ------------------------------------------------------------------------------------


def analyse_alignment(session: Session) -> Analysis:
    """dtheta_h by eq. 26 (0 and 180 deg) or by least squares of eq. 25 (three or more positions)."""
    p = session.meta.get("params", {})
    pts = session.select("static")
    rates = np.array([q.measured_rate_radps(session.station.pulses_per_rev) for q in pts])
    pos = np.array([q.position_deg for q in pts])
    if sorted(np.round(pos % 360, 9)) == [0.0, 180.0]:
        at0, at180 = rates[np.isclose(pos % 360, 0)][0], rates[np.isclose(pos % 360, 180)][0]
        sigma_rate = float(np.mean([2 * math.pi / (session.station.pulses_per_rev * q.Tm_s) for q in pts]))
        result = two_position(at0, at180, session.station, kz_radps_per_g=p["kz_radps_per_g"],
                              sigma_rate_radps=sigma_rate, sigma_latitude_rad=math.radians(p["sigma_latitude_deg"]),
                              sigma_kz=p["sigma_kz"])  # fmt: skip
    else:
        result = multi_position(np.radians(pos), rates, session.station)
    doc = result.to_json()
    rows = [
        (k, f"{v['value']:.6e}", "not estimable (no residual dof)" if v.get("sigma") is None or
         not math.isfinite(v["sigma"]) else f"{v['sigma']:.2e}", v["unit"])
        for k, v in doc.items()
        if isinstance(v, dict)
    ]  # fmt: skip
    parts = [
        f"<p>Method: {esc(result.method)}; {len(pts)} static windows at {esc(pos.tolist())} deg.</p>",
        table(("quantity", "value", "σ", "unit"), rows),
        table(
            ("position (deg)", "Tm (s)", "rate (rad/s)"),
            ((f"{q.position_deg:g}", f"{q.Tm_s:.6f}", f"{r:.9e}") for q, r in zip(pts, rates, strict=True)),
        ),
    ]
    angle = doc["dtheta_h"]
    if "expanded_uncertainty" in angle:
        dof = "infinite dof" if angle["effective_dof"] is None else f"{angle['effective_dof']:g} dof"
        sigma = (f"u = {result.sigma_rad:.1e}, U = {angle['expanded_uncertainty']:.1e} rad (k = "
                 f"{angle['coverage_factor']:.2f} at {dof}, 95 %)")  # fmt: skip
    else:
        sigma = "sigma not estimable (no residual dof)"
    summary = f"misalignment {result.dtheta_h_rad:.3e} rad, {sigma} ({result.method})"
    return Analysis({"alignment": doc}, document("Self-alignment (seed 000 eqs. 25-27)", parts), summary)


@procedure(
    "integral_precession.self_alignment",
    "Self-alignment: the PIGA's misalignment angle from static windows (seed 000 eqs. 25-27)",
    (
        _positions([0.0, 60.0, 180.0, 300.0], "static positions: 0 and 180 for eq. 26, or three or more for eq. 25"),
        COMMON[1],
        COMMON[2],
        Param(
            "kz_radps_per_g",
            float,
            default=constants.KZ_RADPS_PER_G,
            min=0.01,
            max=10.0,
            unit="rad/s/g",
            help="kz from the gravity-field test (eq. 26 only)",
        ),
        Param("sigma_kz", float, default=1e-4, min=0.0, max=1.0, unit="rad/s/g", help="its uncertainty (eq. 27)"),
        Param("sigma_latitude_deg", float, default=0.1, min=0.0, max=10.0, unit="deg", help="latitude uncertainty"),
    ),
    analyse=analyse_alignment,
)
def self_alignment(p: dict):
    for i, pos in enumerate(p["positions_deg"]):
        yield MeasurePoint(f"A{i + 1:02d}-{pos:g}deg-s", float(pos), 0.0, preset_pulses(pos, p["window_s"]),
                           p["settle_s"])  # fmt: skip
