"""Self-contained HTML report of a calibration session (plots as inline SVG, no external assets).

Coefficients with their GUM uncertainties (u_A, u_c, nu_eff, k, U), evaluation (eq. 21's
sigma and the per-rate sigma, eq. 28 as the seed defines it beside the joint variant), residual and
proportional-residual plots in the manner of seed 000 Figs. 10-11, the timing
capture table in the manner of Table 8, and the station and instrument configuration.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import replace

import matplotlib.pyplot as plt
import numpy as np

from procedures.common.certificate import Certificate, InstrumentSpec, budget_rows
from procedures.common.session_certificate import Certified, MethodCard, session_certificate
from procedures.common.uncertainty import MIN_RELIABLE_DOF, coverage_factor
from procedures.integral_precession.budget import (
    SEED000_REFERENCES,
    TABLE_ERRORS_HEADER,
    table_error_rows,
    traceability_keys,
)
from procedures.integral_precession.identify import Identification
from station.htmlkit import document, esc, mapping_table, svg, table
from station.session import Session
from station.twin.regressors import COEFFICIENTS

_UNITS = {"kz": "rad/s/g", "kzz": "rad/s/g²", "ky": "rad/s/g²", "k3": "rad/s/g³"}


def _fmt(x: float, spec: str = ".2e") -> str:
    """A number, or the reason there is none (no nan in a report)."""
    if x is None or not math.isfinite(x):
        return "∞ (Type B only)" if x == math.inf else "not available"
    return format(x, spec)


def _coef_table(results: Mapping[str, Identification], truth: Mapping[str, float] | None) -> str:
    head = "<tr><th class=l>coefficient</th><th class=l>unit</th>"
    for m in results:
        head += f"<th>{esc(m)} value</th><th>u<sub>A</sub> (eq. 22)</th><th>u<sub>c</sub></th><th>ν<sub>eff</sub></th>"
        head += "<th>k (95 %)</th><th>U</th>"
        if truth:
            head += f"<th>{esc(m)} error / u<sub>c</sub></th>"
    if truth:
        head += "<th>true (twin)</th>"
    rows = [head + "</tr>"]
    span = 7 if truth else 6
    for name in COEFFICIENTS:
        row = f"<tr><td class=l>{name}</td><td class=l>{_UNITS[name]}</td>"
        for r in results.values():
            if name in r.names:
                v, s = r.coefficient(name)
                j = r.names.index(name)
                if r.budget is not None:
                    u, nu = r.budget.standard_uncertainty()[j], r.budget.effective_dof()[j]
                    k = r.budget.coverage_factors()[j]
                else:
                    u, nu, k = s, float(r.dof), coverage_factor(r.dof)
                row += f"<td>{v:.6e}</td><td>{s:.2e}</td><td>{u:.2e}</td><td>{_fmt(nu, '.1f')}</td><td>{k:.2f}</td>"
                row += f"<td>{k * u:.2e}</td>"
                if truth:
                    row += f"<td>{(v - truth[name]) / u:+.2f}</td>"
            else:
                row += f"<td colspan={span}>not identifiable by this model</td>"
        if truth:
            row += f"<td>{truth[name]:.6e}</td>"
        rows.append(row + "</tr>")
    tail = "<td></td>" if truth else ""
    ev = "<tr><td class=l>σ of one rate (joint fit)</td><td class=l>rad/s</td>"
    ev21 = "<tr><td class=l>σ of Y (eq. 21)</td><td class=l>rad/s</td>"
    mu = "<tr><td class=l>μ vs μc (eq. 28, residuals of Y)</td><td class=l></td>"
    muj = "<tr><td class=l>μ vs μc (variant: joint residuals)</td><td class=l></td>"
    for r in results.values():
        ev += f"<td colspan={span}>{_fmt(r.sigma_residual, '.3e')} (dof {r.dof}, weights: {esc(r.weighting)})</td>"
        ev21 += f"<td colspan={span}>{_fmt(r.sigma_Y_eq21, '.3e')} (n = {len(r.vib_ids)} test points)</td>"
        cls = "ok" if r.reliable else "bad"
        verdict = "no outlier" if r.reliable else "possible outlier"
        mu += f"<td colspan={span} class={cls}>{_fmt(r.mu_eq28, '.3f')} vs {_fmt(r.mu_c_eq28, '.3f')}: {verdict}</td>"
        muj += f"<td colspan={span}>{_fmt(r.mu, '.3f')} vs {_fmt(r.mu_c, '.3f')} (N = {r.n_points})</td>"
    rows += [x + tail + "</tr>" for x in (ev, ev21, mu, muj)]
    notes = [
        "<p>u<sub>A</sub>: the fit's standard uncertainty (eq. 22, Type A); u<sub>c</sub>: combined with every Type B "
        "input of the budget (GUM); ν<sub>eff</sub> by Welch-Satterthwaite; k from Student's t at 95 % (times the "
        "shapes' factor where rectangular inputs dominate: procedures.common.uncertainty). "
        "σ of one rate is the residual σ of the joint fit of all measured rates; eq. 21's σ is that of "
        "Y = vibration − static rate, which carries the static point's noise as well (about √2 larger). "
        "Eq. 28 is tested as the seed defines it, on the residuals of Y with N the number of test points; the joint "
        "variant (all rates, N all points) sees about μ/√2 and is shown for comparison only.</p>"
    ]
    for m, r in results.items():
        if r.first_passage_bias:
            notes.append(f"<p class=bad>{esc(m)}: " + "; ".join(f"{n}: {esc(r.bias_note(n))}"
                                                                 for n in r.first_passage_bias) + ".</p>")  # fmt: skip
        few = r.budget.few_dof() if r.budget is not None else ([] if r.dof >= MIN_RELIABLE_DOF else list(r.names))
        if few:
            notes.append(
                f"<p class=bad>{esc(m)}: {', '.join(few)} rest on fewer than {MIN_RELIABLE_DOF} effective degrees of "
                f"freedom ({r.dof} in the fit): σ itself is uncertain by about {100 / math.sqrt(2 * r.dof):.0f} %, "
                "so U uses Student's t (k above) and a design with more points is advised for a reliable "
                "uncertainty.</p>"
            )
    return "<table>" + "".join(rows) + "</table>" + "".join(notes)


CARD = MethodCard(
    title="Calibration certificate: PIGA nonlinear error coefficients",
    method="integral precession on the linear vibration table (seed 000 eqs. 19-22, exact window means)",
    procedure="integral_precession",
    procedure_title="",
    references=SEED000_REFERENCES,
)
RESIDUAL_CAPTION = "Residuals of Y (eq. 21), each identification on its own axis, and proportional residuals (eq. 29)"


def residual_figure(results: Mapping[str, Identification]):
    """Residuals of Y (eq. 21) per method on their own axis, and proportional residuals (eq. 29), legends outside."""
    n = len(results)
    fig, axes = plt.subplots(n + 1, 1, figsize=(7.5, 2.3 * (n + 1)), squeeze=False)
    axes = axes[:, 0]
    for ax, ((m, r), marker) in zip(axes[:n], zip(results.items(), "os^", strict=False), strict=False):
        x = np.arange(1, r.Y_residuals_eq21.size + 1)
        ax.axhline(0, color="0.5", lw=0.6)
        ax.plot(x, r.Y_residuals_eq21 * 1e6, marker=marker, ls="-", lw=0.8, ms=3.5, label=f"{m}: e of Y")
        ax.axhspan(-r.sigma_Y_eq21 * 1e6, r.sigma_Y_eq21 * 1e6, color="C0", alpha=0.12, label="±σ (eq. 21)")
        ax.set(ylabel="e (µrad/s)", title=f"{m}: residuals of Y (seed 000 Fig. 10a/11a)")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax = axes[n]
    for (m, r), marker in zip(results.items(), "os^", strict=False):
        x = np.arange(1, r.proportional_residuals.size + 1)
        ax.plot(x, np.abs(r.proportional_residuals), marker=marker, ls="-", lw=0.8, ms=3.5, label=m)
    ax.set(title="Proportional residuals |e / (a cos θ)| (eq. 29)", xlabel="vibration point", ylabel="rad/s/g",
           yscale="log")  # fmt: skip
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    for a in axes:
        a.grid(alpha=0.3)
        a.tick_params(labelsize=8)
    fig.tight_layout()
    return fig


def _residual_plots(results: Mapping[str, Identification]) -> str:
    return svg(residual_figure(results))


def _timing_table(session: Session) -> str:
    static = {round(p.position_deg, 9): p for p in session.points if p.kind == "static"}
    rows = [
        "<tr>"
        + "".join(
            f"<th>{h}</th>" for h in ("position (deg)", "f (Hz)", "Np", "t1 (s)", "Tm (s)", "t2 (s)", "static Tm (s)")
        )
        + "</tr>"
    ]
    for p in session.points:
        if p.kind != "vibration":
            continue
        st = static.get(round(p.position_deg, 9))
        rows.append(
            f"<tr><td>{p.position_deg:g}</td><td>{p.freq_hz:g}</td><td>{p.Np}</td><td>{p.t1_s:.7f}</td>"
            f"<td>{p.Tm_s:.6f}</td><td>{p.t2_s:.7f}</td><td>{f'{st.Tm_s:.6f}' if st else 'none'}</td></tr>"
        )
    return "<table>" + "".join(rows) + "</table>"


def render_report(
    session: Session,
    results: Mapping[str, Identification],
    *,
    title: str = "Calibration session",
    config: Mapping | None = None,
    truth: Mapping[str, float] | None = None,
) -> str:
    """The whole report as one HTML string."""
    serial = session.meta.get("instrument_serial") or "not recorded"
    parts = [
        f"<p>Instrument {esc(serial)}; {len(session.points)} points; {esc(session.notes)}</p>",
        "<h2>Coefficients (integral precession, seed 000 eqs. 19-22; GUM expanded uncertainty)</h2>",
        _coef_table(results, truth),
        "<h2>Uncertainty budget (GUM, JCGM 100)</h2>",
        budget_section(results),
        "<h2>Residuals</h2>",
        _residual_plots(results),
        "<h2>Timing capture (as seed 000 Table 8)</h2>",
        _timing_table(session),
        "<h2>Station</h2>" + mapping_table(vars(session.station)),
    ]
    if config:
        parts.append("<h2>Configuration</h2><pre>" + esc(json.dumps(config, indent=2, default=str)) + "</pre>")
    return document(title, parts)


# ---- budget and certificate ------------------------------------------------------------------------------


def budget_section(results: Mapping[str, Identification]) -> str:
    parts = []
    for m, r in results.items():
        if r.budget is None:
            continue
        header, rows = budget_rows(r.budget, with_sensitivity=True)
        parts.append(f"<h3>{esc(m)}</h3>" + table(header, rows))
    return "".join(parts)


def certificate(
    session: Session,
    results: Mapping[str, Identification],
    primary: str,
    *,
    spec: InstrumentSpec | None = None,
    procedure_title: str = "",
) -> Certificate:
    """The calibration certificate of a seed-000 session from its `primary` identification (with a budget)."""
    r = results[primary]
    if r.budget is None:
        raise ValueError(f"identification {primary!r} has no uncertainty budget: a certificate needs one")
    reliability = (
        f"Reliability (seed 000 eq. 28 on the residuals of Y): μ = {_fmt(r.mu_eq28, '.2f')} against μc = "
        f"{_fmt(r.mu_c_eq28, '.2f')}: {'no outlier' if r.reliable else 'POSSIBLE OUTLIER: results to be reviewed'}. "
        f"σ of Y (eq. 21) {_fmt(r.sigma_Y_eq21, '.3e')} rad/s; σ of one rate (joint fit) {r.sigma_residual:.3e} "
        f"rad/s with {r.dof} degrees of freedom."
    )
    params = session.meta.get("params", {})
    table_errors = table_error_rows(params, compensated=primary == "integral_compensated")
    return session_certificate(
        session,
        [Certified(r.budget)],
        replace(CARD, procedure_title=procedure_title, references=traceability_keys(params)),
        spec=spec,
        extra_tables=[("Table errors: compensated or not", TABLE_ERRORS_HEADER, table_errors)],
        figures=[(RESIDUAL_CAPTION, lambda: residual_figure({primary: r}))],
        remarks=[reliability, *(f"{n}: {r.bias_note(n)}." for n in r.first_passage_bias)],
        identification=[("identification", f"{r.method}, weighted joint least squares ({r.weighting})")],
    )
