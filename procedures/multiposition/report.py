"""HTML reports of seed 003: the gravity-field session and the design of a position sequence."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np

from procedures.common.certificate import budget_rows
from procedures.multiposition.alignment import ALIGNMENT_ANGLES_DEG
from procedures.multiposition.design import (
    efficiency_sensitivity,
    static_rate_estimate_radps,
    total_test_time_s,
    uncertainty_factors,
    window_s,
)
from procedures.multiposition.four_pose import angle_error_rad, harmonic_names
from procedures.multiposition.gravity_field import IDENTIFIABILITY, Calibration, GravityFieldResult
from procedures.multiposition.lsq import UNITS
from procedures.multiposition.sequences import SCHEMES, sequence_deg
from procedures.multiposition.static_model import relative_fitting_accuracy_g
from station.htmlkit import document, esc, svg, table
from station.session import StationInfo

ARCSEC_PER_RAD = 180 / math.pi * 3600


def _coefficient_rows(cal: Calibration, terms: tuple[str, ...]) -> list[tuple]:
    unc, comp, total = cal.uncompensated, cal.compensated, cal.compensated_total
    rows = []
    for t in terms:
        v, s = unc.value(t)
        row = [t, UNITS[t], f"{v:.6e}", f"{s:.2e}"]
        if comp is not None and total is not None:
            row += [f"{comp.value(t)[0]:.6e}", f"{comp.value(t)[1]:.2e}", f"{total.value(t)[1]:.2e}"]
        rows.append(tuple(row))
    sig = ["σ residual", "rad/s", f"{unc.sigma_residual:.2e}", f"dof {unc.dof}"]
    if comp is not None:
        sig += [f"{comp.sigma_residual:.2e}", f"dof {comp.dof}", ""]
    return [*rows, tuple(sig)]


def _calibration_section(res: GravityFieldResult) -> list[str]:
    parts = ["<h2>Calibration of PIGA A without and with the angle-error compensation (Tables 3-4, 7)</h2>",
             f"<p>{esc(IDENTIFIABILITY)}</p>"]  # fmt: skip
    parts += [f"<p class=bad>{esc(e)}</p>" for e in res.calibration_errors]
    if not res.calibrations:
        return [*parts, "<p>No calibration sequence in this session.</p>"]
    fig, axes = plt.subplots(1, len(res.calibrations), figsize=(5.5 * len(res.calibrations), 3.4), squeeze=False)
    for cal, ax in zip(res.calibrations, axes[0], strict=True):
        head = ("term", "unit", "uncompensated", "σ (eq. 49)", "compensated", "σ (eq. 49)",
                "σ with the harmonics' uncertainty")  # fmt: skip
        parts += [f"<h3>{esc(cal.scheme)}, {len(cal.positions_deg)} positions</h3>",
                  table(head, _coefficient_rows(cal, res.terms))]  # fmt: skip
        for name, budget in cal.budgets.items():  # GUM budgets (procedures.multiposition.budget)
            parts += [f"<h4>Uncertainty budget, {esc(name)} (GUM; contributions |c| u)</h4>",
                      table(*budget_rows(budget, with_sensitivity=True))]  # fmt: skip
        for name, fit in (("uncompensated", cal.uncompensated), ("compensated", cal.compensated)):
            if fit is not None:
                rfa = relative_fitting_accuracy_g(fit)
                ax.plot(np.arange(1, rfa.size + 1), rfa, "o-", ms=3, label=f"{name}, max {np.max(np.abs(rfa)):.1e} g")
        ax.set(title=f"relative fitting accuracy e/kz, {cal.scheme}", xlabel="position i", ylabel="g")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    return [*parts, svg(fig)]


def _four_pose_section(res: GravityFieldResult) -> list[str]:
    parts = ["<h2>Angle-error harmonics by the orthogonal 4-pose method (Table 6)</h2>"]
    fp = res.four_pose
    if fp is None:
        return [*parts, f"<p class=bad>{esc(res.four_pose_error)}</p>"]
    rows = [
        (n, f"{v:.4e}", f"{s:.1e}", f"{v * ARCSEC_PER_RAD:.3f}", f"{s * ARCSEC_PER_RAD:.3f}")
        for n, v, s in zip(harmonic_names(fp.order), fp.harmonics_rad, fp.harmonic_sigmas_rad, strict=True)
    ]
    offsets = [(f"δ {i}, setup {s}", f"{fp.offset_rad(i, s):.4e}", f"{fp.fit.value(f'delta {i} setup {s}')[1]:.1e}",
                f"{fp.offset_rad(i, s) * ARCSEC_PER_RAD:.3f}", "") for i, s in fp.groups]  # fmt: skip
    coef = [(f"{i} {t}", UNITS[t], f"{v:.6e}", f"{s:.2e}") for i in fp.instruments
            for t, (v, s) in fp.coefficients(i).items()]  # fmt: skip
    theta = np.linspace(0, 2 * np.pi, 361)
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(np.degrees(theta), angle_error_rad(theta, fp.harmonics_rad) * ARCSEC_PER_RAD)
    ax.set(title="identified head angle error", xlabel="head angle (deg)", ylabel="arc seconds")
    ax.grid(alpha=0.3)
    n_win = fp.fit.residuals.size
    return [*parts,
            f"<p>{n_win} windows of PIGAs {', '.join(fp.instruments)} in setups {sorted({s for _, s in fp.groups})}, "
            f"one least squares (seed 003 eqs. 18-42 in one step); residual σ {fp.fit.sigma_residual:.2e} rad/s, "
            f"dof {fp.fit.dof}.</p>",
            table(("harmonic", "value (rad)", "σ (rad)", "value (″)", "σ (″)"), rows + offsets),
            table(("coefficient", "unit", "value", "σ"), coef), svg(fig)]  # fmt: skip


def _windows_section(res: GravityFieldResult) -> list[str]:
    fig, ax = plt.subplots(figsize=(7, 3.2))
    for inst in sorted({w.instrument for w in res.windows}):
        ws = [w for w in res.windows if w.instrument == inst]
        ang = [math.degrees(w.theta_rad) % 360 for w in ws]
        ax.semilogy(ang, [w.Tm_s for w in ws], "o", ms=3, label=f"PIGA {inst}")
    ax.set(title="window length per head position", xlabel="head angle (deg)", ylabel="Tm (s)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    total_h = sum(w.Tm_s for w in res.windows) / 3600
    return [
        "<h2>Test time</h2>",
        f"<p>{len(res.windows)} windows, {total_h:.2f} h of counting; where an "
        "instrument's input axis is near horizontal its rate is k0 and the earth rate alone.</p>",
        svg(fig),
    ]


def gravity_field_report(res: GravityFieldResult, title: str, params: dict) -> str:
    align = [
        (
            a["setup"],
            a["round"],
            f"{a['misalignment_rad']:.3e}",
            f"{a['sigma_rad']:.1e}",
            f"{a['misalignment_rad'] * ARCSEC_PER_RAD:.2f}",
            f"{a['zero_deg']:.6f}",
        )
        for a in res.alignments
    ]
    parts = ["<h2>Self-alignment (eqs. 52-56)</h2>",
             table(("setup", "round", "θ0 (rad)", "σ (rad)", "θ0 (″)", "head zero (deg)"), align),
             *_four_pose_section(res), *_calibration_section(res), *_windows_section(res),
             "<h2>Parameters</h2>", table(("parameter", "value"), params.items())]  # fmt: skip
    return document(title, parts)


def design_report(terms: tuple[str, ...], ns: np.ndarray, n_chosen: int, precession_rad: float, k0_radps: float,
                  kz_radps_per_g: float, station: StationInfo) -> tuple[str, dict]:  # fmt: skip
    """d_ii (Fig. 4), ES(n) (Fig. 5), total test time (Figs. 6-7) and the window per position; (html, results)."""
    results: dict = {"n": ns.tolist(), "terms": list(terms)}
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.4))
    for scheme in SCHEMES:
        d = np.array([uncertainty_factors(sequence_deg(scheme, int(n)), terms) for n in ns])
        es = efficiency_sensitivity(scheme, ns, terms)
        t = np.array([total_test_time_s(scheme, int(n), precession_rad, k0_radps, kz_radps_per_g, station)
                      for n in ns])  # fmt: skip
        results[scheme] = {
            "d_ii": {k: d[:, i].tolist() for i, k in enumerate(terms)},
            "ES": [None if math.isnan(x) else float(x) for x in es],
            "total_test_time_s": t.tolist(),
        }
        ax[0].semilogy(ns, d[:, 0], "o-", ms=3, label=f"{scheme} d11 ({terms[0]})")
        ax[0].semilogy(ns, d[:, 1], "s--", ms=3, label=f"{scheme} d22 ({terms[1]})")
        ax[1].plot(ns, es, "o-", ms=3, label=scheme)
        ax[2].semilogy(ns, t / 60, "o-", ms=3, label=scheme)
    for a, title in zip(ax, ("uncertainty factors d_ii (Fig. 4)", "ES(n) (Fig. 5)", "t_total, min (Figs. 6-7)"),
                        strict=True):  # fmt: skip
        a.set(title=title, xlabel="n")
        a.legend(fontsize=7)
        a.grid(alpha=0.3)
    ax[1].set_ylim(-1, 1)
    horizontal = np.radians(ALIGNMENT_ANGLES_DEG)
    hours = window_s(precession_rad, static_rate_estimate_radps(horizontal, k0_radps, kz_radps_per_g, station)) / 3600
    results["window_s_input_axis_horizontal"] = dict(zip(("90", "270"), (hours * 3600).tolist(), strict=True))
    rows, per_position = [], []
    for scheme in SCHEMES:
        d = uncertainty_factors(sequence_deg(scheme, n_chosen), terms)
        total_s = total_test_time_s(scheme, n_chosen, precession_rad, k0_radps, kz_radps_per_g, station)
        rows.append((scheme, *(f"{x:.3e}" for x in d), f"{total_s / 60:.1f}"))
        theta = np.radians(sequence_deg(scheme, n_chosen))
        rate = static_rate_estimate_radps(theta, k0_radps, kz_radps_per_g, station)
        t_s = window_s(precession_rad, rate)
        results[scheme]["window_s_by_position"] = dict(zip(map(str, np.degrees(theta)), t_s.tolist(), strict=True))
        per_position += [(scheme, f"{math.degrees(th):.4f}", f"{math.cos(th):+.4f}", f"{r:.4e}", f"{t / 60:.2f}")
                         for th, r, t in zip(theta, rate, t_s, strict=True)]  # fmt: skip
    parts = [f"<p>Model terms {esc(', '.join(terms))}; preset precession {precession_rad / math.pi:g} π rad per "
             f"position; rate estimate k0 + kz cos θ − w_ie sin(λ − θ) with k0 = {k0_radps:g} rad/s, "
             f"kz = {kz_radps_per_g:g} rad/s/g. With the input axis horizontal the rate is k0 and the earth "
             f"rate alone: a window at 90 deg takes {hours[0]:.1f} h, at 270 deg {hours[1]:.1f} h, so every "
             "n = 4k design (which has both positions) costs that much more.</p>", svg(fig),
             f"<h2>{n_chosen} positions</h2>",
             table(("scheme", *(f"d {t}" for t in terms), "t_total (min)"), rows),
             "<h2>Test time per position</h2>",
             table(("scheme", "position (deg)", "aI (g)", "rate (rad/s)", "window (min)"), per_position)]  # fmt: skip
    return document("Position sequence design on the indexing head (seed 003 5.1-5.2)", parts), results
