"""Analysis and report of a seed-002 session: flexure coefficients, their uncertainties, compensation.

From the runs' stored observations (`procedures.rlg_g_sensitivity.procedure.VibrationRun`): the least squares of
eq. 21 over the calibration runs (Table 1's coefficients in arcsec/g with their sigma), the
residuals, and for the verification runs the velocity error with and without compensation
(Figs. 6-7) and its percentage decrease (Table 2), beside what the estimate's covariance
predicts for the compensated error.
"""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
from scipy.stats import chi2

from procedures.common.certificate import budget_rows
from procedures.common.session_certificate import issue_certificate, result_provenance, session_uid
from procedures.common.uncertainty import merged_json
from procedures.rlg_g_sensitivity.analysis import FlexureFit, estimate_flexure, run_weights
from procedures.rlg_g_sensitivity.budget import SEED002_TYPE_B, flexure_budget
from procedures.rlg_g_sensitivity.certificate import VERIFY_HEADER, certificate, verification_rows
from station.engine.registry import Analysis
from station.htmlkit import document, mapping_table, svg, table
from station.least_squares import FitError
from station.session import Measurement, Session
from station.twin.fixture_poses import POSES
from station.twin.strapdown_imu import ARCSEC_PER_G, ARCSEC_RAD, TABLE1_ARCSEC_PER_G, TAU_NAMES, Site

KIND = "seed002_run"
RUNS_HEADER = ("run", "pose (Fig. 3)", "vibration along", "for", "vibration s", "max |<ω f>| (rad/s·m/s²)",
               "φ east, north (arcsec)", "residual (arcsec)")  # fmt: skip


def runs_of(session: Session, role: str) -> list[Measurement]:
    return [m for m in session.measurements if m.kind == KIND and m.values["role"] == role]


def fit_session(session: Session) -> FlexureFit:
    """Eq. 21 over the session's calibration runs."""
    runs = runs_of(session, "calibration")
    if not runs:
        raise FitError("the session holds no calibration run")
    values = [m.values for m in runs]
    return estimate_flexure(np.vstack([v["A"] for v in values]), np.concatenate([v["B"] for v in values]),
                            run_weights(values))  # fmt: skip


def predicted_sigma_mps(run: Measurement, fit: FlexureFit) -> float:
    """RMS horizontal velocity error at the run's end that tau_hat's covariance alone leaves: sqrt(tr(S C S^T))."""
    s = np.asarray(run.values["sensitivity_end"])
    return float(math.sqrt(np.trace(s @ fit.cov @ s.T)))


def _verification(runs: list[Measurement], fit: FlexureFit) -> list[dict]:
    out = []
    for m in runs:
        v = m.values
        out.append({
            "key": m.key, "mode": v["mode"], "pose": v["pose"], "level_g": v["level_g"], "freq_hz": v["freq_hz"],
            "band_hz": v["band_hz"], "vibration_s": v["vibration_s"], "decrease_pct": v["decrease_pct"],
            "v_end_uncompensated_mps": float(np.linalg.norm(v["v_uncompensated_mps"][-1])),
            "v_end_compensated_mps": float(np.linalg.norm(v["v_compensated_mps"][-1])),
            "predicted_sigma_mps": predicted_sigma_mps(m, fit),
        })  # fmt: skip
    return out


def _coefficient_table(fit: FlexureFit) -> str:
    rows = [
        (f"τ_{n}", f"{v / ARCSEC_PER_G:+.4f}", f"{s / ARCSEC_PER_G:.4f}", f"{t:+.3f}")
        for n, v, s, t in zip(TAU_NAMES, fit.values, fit.sigmas, TABLE1_ARCSEC_PER_G, strict=True)
    ]
    return table(("coefficient", "estimate (arcsec/g)", "σ (arcsec/g)", "seed Table 1 (arcsec/g)"), rows)


def _runs_table(runs: list[Measurement], fit: FlexureFit) -> str:
    rows = []
    residuals = fit.residuals.reshape(-1, 2) / ARCSEC_RAD
    for m, e in zip(runs, residuals, strict=True):
        v = m.values
        pose = POSES[v["pose"]]
        b = np.asarray(v["B"]) / ARCSEC_RAD
        peak = np.abs(np.asarray(v["mean_products"])).max()
        where = f"{pose.number} ({pose.panel})"
        rows.append((m.key, where, pose.vibration, ", ".join(pose.targets), f"{v['vibration_s']:.0f}", f"{peak:.3g}",
                     f"{b[0]:+.3f}, {b[1]:+.3f}", f"{e[0]:+.3f}, {e[1]:+.3f}"))  # fmt: skip
    return table(RUNS_HEADER, rows)


def _snippet_figure(run: Measurement) -> str:
    """The rate and force pair of largest product in a short stretch (seed 002 Fig. 5)."""
    v = run.values
    products = np.abs(np.asarray(v["mean_products"]))
    j, k = np.unravel_index(int(np.argmax(products)), products.shape)
    rate = np.degrees(np.asarray(v["snippet_rate_radps"])[:, j])
    force = np.asarray(v["snippet_force_mps2"])[:, k] / 9.8
    t = np.arange(rate.size) / v["rate_hz"]
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.plot(t, force - force.mean(), color="C0", label=f"f_{'xyz'[k]} (g, mean removed)")
    ax.set(xlabel="s", ylabel="g", title=f"{run.key}: specific force and angular rate (Fig. 5)")
    ax2 = ax.twinx()
    ax2.plot(t, rate, color="C3", label=f"ω_{'xyz'[j]} (deg/s)")
    ax2.set_ylabel("deg/s")
    lines = ax.get_lines() + ax2.get_lines()
    ax.legend(handles=lines, loc="upper left", bbox_to_anchor=(1.1, 1.0))
    return svg(fig)


def _velocity_figure(runs: list[Measurement]) -> str:
    """Horizontal velocity error with and without compensation (seed 002 Figs. 6-7)."""
    fig, axes = plt.subplots(1, len(runs), figsize=(5.5 * len(runs), 3.6), squeeze=False)
    for ax, m in zip(axes[0], runs, strict=True):
        v = m.values
        t = np.asarray(v["t_s"])
        ax.plot(t, np.linalg.norm(v["v_uncompensated_mps"], axis=1), label="uncompensated")
        ax.plot(t, np.linalg.norm(v["v_compensated_mps"], axis=1), label="compensated")
        ax.set(title=f"{m.key}: −{v['decrease_pct']:.1f} %", xlabel="s from the vibration's start",
               ylabel="horizontal velocity error (m/s)")  # fmt: skip
        ax.grid(alpha=0.3)
        ax.legend()
    return svg(fig)


def analyse_session(session: Session) -> Analysis:
    """The flexure coefficients (eq. 21) and the verification runs, with the session's report and certificate."""
    fit = fit_session(session)
    calibration, verification = runs_of(session, "calibration"), runs_of(session, "verification")
    names = list(TAU_NAMES)
    flexure = {
        "names": names,
        "values_arcsec_per_g": (fit.values / ARCSEC_PER_G).tolist(),
        "sigmas_arcsec_per_g": (fit.sigmas / ARCSEC_PER_G).tolist(),
        "values_rad_per_mps2": fit.values.tolist(),
        "cov_rad_per_mps2": fit.cov.tolist(),
        "sigma_residual_arcsec": fit.sigma_residual / ARCSEC_RAD,
        "dof": fit.dof,
        "condition": fit.condition,
        "runs": [m.key for m in calibration],
    }
    # GUM fields of the flexure coefficients in arcsec/g: the fit (Type A) and the Type B rows
    # (procedures.rlg_g_sensitivity.budget)
    st = session.station
    budget = flexure_budget([m.values for m in calibration], Site(st.g_mps2, st.earth_rate_radps, st.latitude_rad))
    gum_coefs = {n: {"value": float(v), "sigma": float(s)} for n, v, s in
                 zip(names, fit.values / ARCSEC_PER_G, fit.sigmas / ARCSEC_PER_G, strict=True)}  # fmt: skip
    flexure["gum"] = {"coefficients": gum_coefs, **merged_json(gum_coefs, budget, SEED002_TYPE_B)}
    checks = _verification(verification, fit)
    results = {"flexure": flexure | {"provenance": result_provenance(session)}, "verification": {"runs": checks}}
    uid = session_uid(session)
    low, high = np.sqrt(fit.dof / chi2.ppf([0.95, 0.05], fit.dof))  # the true sigma over the estimate, 90 %
    fit_facts = {
        "residual σ": f"{fit.sigma_residual / ARCSEC_RAD:.3f} arcsec ({fit.dof} degrees of freedom)",
        "σ's own uncertainty": f"the true σ lies in {low:.2f} .. {high:.2f} times it (90 %, χ² with {fit.dof} dof); "
        "so do the coefficients' σ",
        "condition number of A": f"{fit.condition:.2f}",
        "observations": f"{len(calibration)} runs × 2 horizontal components",
    }
    parts = [
        "<h2>Flexure coefficients (seed 002 eq. 21, Table 1)</h2>",
        _coefficient_table(fit),
        mapping_table(fit_facts),
        "<h2>Uncertainty budget (GUM; contributions |c| u in arcsec/g)</h2>",
        table(*budget_rows(budget, with_sensitivity=True)),
        "<h2>Calibration runs (Fig. 3 poses, eqs. 17-22)</h2>",
        _runs_table(calibration, fit),
        _snippet_figure(calibration[0]),
    ]
    if verification:
        parts += [
            "<h2>Verification: velocity error after compensation (Figs. 6-7, Table 2)</h2>",
            table(VERIFY_HEADER, verification_rows(checks)),
            _velocity_figure(verification),
        ]
    html = document(f"Session {uid}: g-sensitive misalignment calibration (seed 002)", parts)
    coefficients = zip(names, flexure["values_arcsec_per_g"], flexure["sigmas_arcsec_per_g"], strict=True)
    lines = [
        ", ".join(f"τ_{n} = {v:+.3f} ± {s:.3f}" for n, v, s in coefficients) + " arcsec/g",
        f"residual σ = {flexure['sigma_residual_arcsec']:.3f} arcsec, {fit.dof} dof, condition {fit.condition:.2f}",
    ]
    lines += [
        f"{c['key']}: velocity error {c['v_end_uncompensated_mps']:.4f} -> {c['v_end_compensated_mps']:.4f} m/s "
        f"(-{c['decrease_pct']:.1f} %)"
        for c in checks
    ]
    files, why_not = issue_certificate(lambda: certificate(session, fit, budget, calibration, checks), uid)
    return Analysis(results, html, "\n".join(filter(None, [*lines, why_not])), files)
