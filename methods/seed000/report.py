"""Self-contained HTML report of a calibration session (plots as inline SVG, no external assets).

Coefficients with uncertainties, evaluation (sigma, mu vs mu_c), residual and
proportional-residual plots in the manner of seed 000 Figs. 10-11, the timing
capture table in the manner of Table 8, and the station and instrument configuration.
"""

from __future__ import annotations

import json
from collections.abc import Mapping

import matplotlib.pyplot as plt
import numpy as np

from methods.seed000.identify import Identification
from models.regressors import COEFFICIENTS
from station.htmlkit import document, esc, mapping_table, svg
from station.session import Session

_UNITS = {"kz": "rad/s/g", "kzz": "rad/s/g²", "ky": "rad/s/g²", "k3": "rad/s/g³"}


def _coef_table(results: Mapping[str, Identification], truth: Mapping[str, float] | None) -> str:
    head = "<tr><th class=l>coefficient</th><th class=l>unit</th>"
    for m in results:
        head += f"<th>{esc(m)} value</th><th>{esc(m)} σ</th>"
        if truth:
            head += f"<th>{esc(m)} error</th>"
    if truth:
        head += "<th>true (twin)</th>"
    rows = [head + "</tr>"]
    for name in COEFFICIENTS:
        row = f"<tr><td class=l>{name}</td><td class=l>{_UNITS[name]}</td>"
        for r in results.values():
            if name in r.names:
                v, s = r.coefficient(name)
                row += f"<td>{v:.6e}</td><td>{s:.2e}</td>"
                if truth:
                    row += f"<td>{v - truth[name]:+.2e}</td>"
            else:
                row += "<td>—</td><td>—</td>" + ("<td>—</td>" if truth else "")
        if truth:
            row += f"<td>{truth[name]:.6e}</td>"
        rows.append(row + "</tr>")
    ev = "<tr><td class=l>σ residual</td><td class=l>rad/s</td>"
    mu = "<tr><td class=l>μ vs μc (eq. 28)</td><td class=l></td>"
    span = 3 if truth else 2
    for r in results.values():
        ev += f"<td colspan={span}>{r.sigma_residual:.3e} (dof {r.dof})</td>"
        cls = "ok" if r.mu < r.mu_c else "bad"
        verdict = "accepted" if r.mu < r.mu_c else "possible outlier"
        mu += f"<td colspan={span} class={cls}>{r.mu:.3f} vs {r.mu_c:.3f}: {verdict}</td>"
    tail = "<td></td>" if truth else ""
    rows += [ev + tail + "</tr>", mu + tail + "</tr>"]
    return "<table>" + "".join(rows) + "</table>"


def _residual_plots(results: Mapping[str, Identification]) -> str:
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    for (m, r), marker in zip(results.items(), "os^", strict=False):
        x = np.arange(1, r.Y_residuals.size + 1)
        axes[0].plot(x, r.Y_residuals, marker=marker, ls="-", lw=0.8, label=m)
        axes[1].plot(x, np.abs(r.proportional_residuals), marker=marker, ls="-", lw=0.8, label=m)
    axes[0].set(title="Residuals e (Fig. 10a/11a)", xlabel="vibration point", ylabel="rad/s")
    axes[1].set(
        title="Proportional residuals |e / (a cos θ)| (eq. 29)",
        xlabel="vibration point",
        ylabel="rad/s/g",
        yscale="log",
    )
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend()
    return svg(fig)


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
            f"<td>{p.Tm_s:.6f}</td><td>{p.t2_s:.7f}</td><td>{st.Tm_s if st else float('nan'):.6f}</td></tr>"
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
        "<h2>Coefficients (integral precession, seed 000 eqs. 19-22)</h2>",
        _coef_table(results, truth),
        "<h2>Residuals</h2>",
        _residual_plots(results),
        "<h2>Timing capture (as seed 000 Table 8)</h2>",
        _timing_table(session),
        "<h2>Station</h2>" + mapping_table(vars(session.station)),
    ]
    if config:
        parts.append("<h2>Configuration</h2><pre>" + esc(json.dumps(config, indent=2, default=str)) + "</pre>")
    return document(title, parts)
