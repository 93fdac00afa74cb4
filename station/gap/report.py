"""The report of a gap diagnosis: `GapReport` (what the diagnosis found, `to_json()` the OUT.json document),
`render(report)`, its self-contained HTML (inline SVG, nothing loaded from elsewhere), and `summary_text(report)`,
its short text summary (what `station gap` prints).

Verdict, held-out gap before and after (metric defined), where the gap lies
(maps of standardised residuals over position x frequency, run order with
static vs vibration, the period identities, and the raw streams' harmonics
when there are any), the ranked candidates with their parameters and
uncertainties, the identifiability report with the test points that would
separate what this design cannot, the noise estimate, and the twin
configuration with the chosen effect(s) switched on.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from matplotlib.figure import Figure

from station import htmlkit
from station.gap.design import PointDesign
from station.gap.heldout import HeldOut, shrink
from station.gap.identifiability import IdentifiabilityReport
from station.gap.verdict import Verdict, family_level
from station.htmlkit import esc, html_fragment, table
from station.jsonsafe import json_safe
from station.twin.config import TwinConfig

FORMAT = "piga-gap/1"


@dataclass
class GapReport:
    """Everything the diagnosis found. `to_json()` is the OUT.json document; the arrays feed the HTML maps."""

    verdict: Verdict
    candidates: list[dict]  # ranked: the chosen effects, then identifiable candidates by BIC, then the rest
    gap_before: HeldOut  # the twin with its calibrated coefficients refitted
    gap_after: HeldOut  # ... and the chosen effects added
    where: dict
    identifiability: IdentifiabilityReport
    noise: dict
    coefficients: dict
    twin_out: TwinConfig  # the twin with the chosen effect(s) switched on (the input twin unless explained)
    session_info: dict
    settings: dict
    elapsed_s: float
    design: PointDesign = field(repr=False)
    z_before: np.ndarray = field(repr=False)  # standardised residual of every point, twin refitted
    z_after: np.ndarray = field(repr=False)  # ... with the chosen effects
    tau_z_before: np.ndarray = field(repr=False)  # standardised period identities of the vibration points
    tau_z_after: np.ndarray = field(repr=False)
    raw: dict = field(default_factory=dict)

    @property
    def effects(self) -> list[str]:
        return list(self.verdict.effects)

    def _repr_html_(self) -> str:
        """Rich display in a notebook: the HTML report's body (render, below)."""
        return html_fragment(render(self))

    def to_json(self) -> dict:
        return json_safe(
            {
                "format": FORMAT,
                **self.verdict.to_json(),
                "candidates": self.candidates,
                "gap_before": self.gap_before.to_json(),
                "gap_after": self.gap_after.to_json(),
                "where": self.where,
                "identifiability": self.identifiability.to_json(),
                "noise": self.noise,
                "calibrated_coefficients": self.coefficients,
                "twin_config": self.twin_out.to_dict(),
                "session": self.session_info,
                "settings": self.settings,
                "elapsed_s": self.elapsed_s,
            }
        )


_VERDICT_CLASS = {"no_gap": "ok", "explained": "ok", "unexplained": "bad", "cannot_tell": "bad"}


def _svg(fig: Figure) -> str:
    """Inline SVG without its RDF metadata and namespace URLs: the page names no address at all."""
    svg = re.sub(r"<metadata>.*?</metadata>", "", htmlkit.svg(fig), flags=re.S)
    return re.sub(r' xmlns(:\w+)?="[^"]*"', "", svg)


def _num(x, fmt: str = ".3g") -> str:
    return "—" if x is None else format(x, fmt)


# ----------------------------------------------------------------------------- maps


def _grid(report: GapReport, z: np.ndarray) -> tuple[np.ndarray, list[float], list[float]]:
    """z of every point on the position x frequency grid (mean where a cell has repeats; NaN if empty)."""
    d = report.design
    freqs = sorted({float(f) for f in d.freq_hz})
    pos = [float(p) for p in d.positions_deg]
    total, count = np.zeros((len(pos), len(freqs))), np.zeros((len(pos), len(freqs)))
    for i in range(d.n_points):
        j, k = int(d.pos_index[i]), freqs.index(float(d.freq_hz[i]))
        total[j, k] += z[i]
        count[j, k] += 1
    with np.errstate(invalid="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan), pos, freqs


def _named(report: GapReport) -> list[str]:
    """The effects the verdict names: explained, partial or those it cannot tell apart."""
    v = report.verdict
    return list(v.effects or v.partial or v.ambiguous)


def _named_entries(report: GapReport) -> list[dict]:
    """The candidate entries of the named effects, in the report's order."""
    named = _named(report)
    return [c for c in report.candidates if c["name"] in named]


def _meaning(report: GapReport) -> list[str]:
    """What each named effect means at the station and which test points separate it (its module's texts,
    station.twin.effects)."""
    items = [
        f"<li><b>{esc(c['name'])}</b> ({esc(c['cause'])}). {esc(c['explanation'])} "
        f"<i>Separated by</i>: {esc(c['separating'])}.</li>"
        for c in _named_entries(report)
        if c.get("explanation")
    ]
    return ["<h2>What the named effect(s) mean</h2>", f"<ul>{''.join(items)}</ul>"] if items else []


def _position_frequency_map(report: GapReport) -> str:
    after = _named(report)
    panels = [("twin, coefficients refitted", report.z_before)]
    if after:
        panels.append((f"with {', '.join(after)}", report.z_after))
    fig = Figure(figsize=(4.2 * len(panels) + 1, 4.2))
    zmax = max(3.0, float(np.nanmax(np.abs(np.concatenate([z for _, z in panels])))))
    for n, (title, z) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), n + 1)
        grid, pos, freqs = _grid(report, z)
        im = ax.imshow(grid, cmap="RdBu_r", vmin=-zmax, vmax=zmax, aspect="auto", origin="lower")
        for (j, k), v in np.ndenumerate(grid):
            if np.isfinite(v):
                ax.text(k, j, f"{v:.1f}", ha="center", va="center", fontsize=7)
        ax.set_xticks(range(len(freqs)), ["static" if f == 0 else f"{f:g}" for f in freqs])
        ax.set_yticks(range(len(pos)), [f"{p:g}" for p in pos])
        ax.set(title=title, xlabel="frequency (Hz)", ylabel="position (deg)")
    fig.colorbar(im, ax=fig.axes, label="standardised residual z")
    return _svg(fig)


def _run_order_plot(report: GapReport) -> str:
    d = report.design
    fig = Figure(figsize=(11, 3.4))
    ax = fig.add_subplot(1, 2, 1)
    for mask, marker, kind in ((~d.vib, "s", "static"), (d.vib, "o", "vibration")):
        ax.scatter(
            d.sequence[mask], report.z_before[mask], marker=marker, s=22, facecolors="none", edgecolors="C0",
            label=f"{kind}, twin refitted",
        )  # fmt: skip
        if report.z_after is not report.z_before:
            ax.scatter(
                d.sequence[mask], report.z_after[mask], marker=marker, s=14, color="C1", label=f"{kind}, with effects"
            )
    ax.axhline(0, color="k", lw=0.6)
    for lim in (-2, 2):
        ax.axhline(lim, color="k", lw=0.4, ls=":")
    ax.set(title="Standardised residuals in run order", xlabel="sequence (run order)", ylabel="z")
    ax.legend(fontsize=7)
    ax = fig.add_subplot(1, 2, 2)
    span = d.Np[d.vib] / d.freq_hz[d.vib]
    ax.scatter(span, report.tau_z_before, s=18, facecolors="none", edgecolors="C0", label="twin refitted")
    if report.tau_z_after is not report.tau_z_before:
        ax.scatter(span, report.tau_z_after, s=14, color="C1", label="with effects")
    ax.axhline(0, color="k", lw=0.6)
    ax.set(
        title="Period identity t2 - t1 + Tm - Np T, standardised",
        xlabel="Np T (s)",
        ylabel="z (timing)",
    )
    ax.legend(fontsize=7)
    return _svg(fig)


def _raw_plot(raw: dict) -> str:
    """Grating harmonics minus the twin's, and the pulse-rate harmonics, per point with raw streams."""
    pts = [p for p in raw.get("points", []) if "grating" in p]
    if not pts:
        return ""
    names = list(pts[0]["grating"])
    fig = Figure(figsize=(11, 3.4))
    ax = fig.add_subplot(1, 2, 1)
    x = np.arange(len(names))
    width = 0.8 / len(pts)
    for k, p in enumerate(pts):
        diff = [p["grating"][n]["difference_m"] * 1e6 for n in names]
        se = [p["grating"][n]["se_m"] * 1e6 for n in names]
        ax.bar(x + k * width, diff, width, yerr=se, label=f"{p['position_deg']:g} deg {p['freq_hz']:g} Hz")
    ax.set_xticks(x + 0.4 - width / 2, names)
    ax.set(title="Grating harmonics, recorded minus twin", ylabel="µm")
    ax.axhline(0, color="k", lw=0.6)
    if len(pts) <= 8:
        ax.legend(fontsize=6)
    ax = fig.add_subplot(1, 2, 2)
    for p in pts:
        h = p.get("pulse_rate_harmonics")
        if isinstance(h, list):
            ax.semilogy([e["harmonic"] for e in h], [max(e["difference_radps"], 1e-12) for e in h], "o-", lw=0.8, ms=3)
    ax.set(title="Pulse-rate harmonics, |recorded - twin|", xlabel="harmonic of the crank frequency", ylabel="rad/s")
    return _svg(fig)


# ----------------------------------------------------------------------------- tables


def _gap_table(report: GapReport) -> str:
    b, a = report.gap_before, report.gap_after
    rows = [
        ["held-out mean z² − 1", _num(b.G), _num(a.G)],
        ["standard error if no gap", _num(b.se), _num(a.se)],
    ]
    rows += [[f"  {k}", _num(v), _num(a.by_scheme.get(k))] for k, v in b.by_scheme.items()]
    rows += [[f"  {k} rows", _num(v), _num(a.by_channel.get(k))] for k, v in b.by_channel.items()]
    rows += [
        ["excess rate RMS (rad/s, T_ref window)", _num(b.rate_excess_rms_radps), _num(a.rate_excess_rms_radps)],
        ["excess period-identity RMS (s)", _num(b.timing_excess_rms_s), _num(a.timing_excess_rms_s)],
    ]
    return table(["held-out gap", "twin (coefficients refitted)", "with the effect(s)"], rows)


def _candidate_table(report: GapReport) -> str:
    rows = []
    for c in report.candidates:
        params = "; ".join(
            f"{k} = {v:.4g} ± {_num(c['uncertainty'].get(k), '.2g')} {c['units'].get(k, '')}"
            for k, v in c["parameters"].items()
        )
        ev = c["evidence"] or {}
        rows.append(
            [
                c["name"] + (" (accepted)" if c["accepted"] else ""),
                _num(c["rank"], "d"),
                "yes" if c["identifiable"] else f"no: {c['identifiability']['reason']}",
                params or "—",
                _num(ev.get("delta_bic"), ".1f"),
                _num(ev.get("p_value"), ".1e"),
                _num(c["heldout_shrink"], ".2f"),
                _rejection(ev),
            ]
        )
    head = ["candidate", "rank", "identifiable", "parameters ± 1σ", "ΔBIC", "p", "held-out shrink", "rejected by"]
    return table(head, rows)


def _rejection(evidence: dict) -> str:
    """The test that rejects a candidate the rates would accept: its plausible bounds, or the pulse record."""
    if evidence.get("beyond_bounds"):
        return "plausible bounds: " + ", ".join(evidence["beyond_bounds"])
    return evidence.get("rejected_by") or "—"


def _identifiability_table(report: GapReport) -> str:
    rows = []
    ratio = report.identifiability.noise_ratio
    for cid in report.identifiability.candidates.values():
        for p in cid.params:
            j = p.to_json(ratio)
            tests = [s["test"] for s in j["separating_test_points"] if s["separates"]]
            extra = "; ".join(tests) if tests else ("—" if not j["separating_test_points"] else "none of those tried")
            if j["raw_stream"]:
                extra += f"; raw streams: {j['raw_stream']}"
            rows.append(
                [
                    p.key,
                    p.status + (f" (with {', '.join(n for n, _ in p.collinear_with)})" if p.collinear_with else ""),
                    _num(j["fraction_not_absorbed"]),
                    _num(j["snr_after_projection_at_typical_magnitude"], ".2g"),
                    f"{_num(j['min_detectable_3sigma'], '.2g')} {p.unit}",
                    extra,
                ]
            )
    head = ["parameter", "status", "not absorbed", "SNR at typical size", "3σ detectable", "would separate it"]
    return table(head, rows)


def _structure_table(report: GapReport) -> str:
    before = report.where["structure_tests_before"]
    after = {t["name"]: t for t in report.where["structure_tests_after"]}
    rows = [
        [
            t["tests"] + (f": {t['at']}" if t.get("at") else ""),
            _num(t["F"], ".2f"),
            _num(t["p_value"], ".1e"),
            _num(after.get(t["name"], {}).get("p_value"), ".1e"),
        ]
        for t in before
    ]
    return table(["structure test", "F (twin)", "p (twin)", "p (with effects)"], rows)


def _noise_table(report: GapReport) -> str:
    n = report.noise
    rows = [
        ["σ0 at T_ref (rad/s)", f"{n['sigma0_radps']:.3g} ({n['source']}, {n['sigma0_dof']} dof)"],
        ["model", n["model"]],
        ["stated by the session", ", ".join(f"{k} {v:g}" for k, v in n["stated_by_session"].items() if v is not None)
         or "nothing (estimated)"],
        ["static model", n["static_model"]],
        ["excess scatter, twin", f"p = {_num(n['excess_scatter_before']['p_value'], '.2g')} "
         f"against the {n['excess_scatter_before']['reference']}"],
        ["excess scatter, with effects", f"p = {_num(n['excess_scatter_after']['p_value'], '.2g')}"],
        ["σ of the period identity (s)", f"{n['timing']['sigma_tau_s']:.3g} ({n['timing']['dof']} dof)"],
    ]  # fmt: skip
    return table(["noise", "value"], rows)


def _coefficient_table(report: GapReport) -> str:
    before, after = report.coefficients["twin_refit"], report.coefficients["with_effects"]
    rows = [
        [k, f"{v['value']:.6e} ± {v['sigma']:.2e}", f"{after[k]['value']:.6e} ± {after[k]['sigma']:.2e}"]
        for k, v in before.items()
    ]
    return table(["coefficient", "twin refitted", "with the effect(s)"], rows)


def render(report: GapReport) -> str:
    """The whole report as one self-contained HTML string."""
    v = report.verdict
    info = report.session_info
    parts = [
        f"<p>{info['n_points']} points ({info['n_vibration']} vibration), positions "
        f"{', '.join(f'{p:g}' for p in info['positions_deg'])} deg, frequencies "
        f"{', '.join(f'{f:g}' for f in info['frequencies_hz'])} Hz; {info['raw_streams']} points with raw streams; "
        f"{info['residual_dof']} residual dof after the calibrated terms; diagnosed in {report.elapsed_s:.1f} s.</p>",
        f"<h2>Verdict: <span class={_VERDICT_CLASS[v.verdict]}>{esc(v.verdict)}</span></h2><p>{esc(v.text)}</p>",
        *_meaning(report),
        "<h2>Held-out gap</h2>",
        "<p>Metric: mean of z² − 1 over held-out vibration points (leave one position, one frequency, one block "
        "of the run order out), z = held-out residual / √(σ² + xᵀ Cov x); 0 when the model is right. "
        "In rate units: the excess RMS of held-out rates over their predictive noise.</p>",
        _gap_table(report),
        "<h2>Where the gap lies</h2>",
        f"<p>{esc(report.where['summary'])}</p>",
    ]
    if report.where.get("after_effects"):
        parts.append(f"<p>After the effect(s): {esc(report.where['after_effects'])}</p>")
    parts += [_position_frequency_map(report), _run_order_plot(report), _structure_table(report)]
    if report.raw:
        parts += ["<h3>Raw streams</h3>", _raw_plot(report.raw)]
    parts += [
        "<h2>Candidates (each fitted with the calibrated coefficients)</h2>",
        _candidate_table(report),
        "<h2>Identifiability in this design</h2>",
        _identifiability_table(report),
        "<h2>Noise</h2>",
        _noise_table(report),
        "<h2>Calibrated coefficients</h2>",
        _coefficient_table(report),
        "<h2>Twin configuration with the effect(s) switched on</h2>",
        f"<pre>{esc(report.twin_out.to_toml())}</pre>",
    ]
    return htmlkit.document("Sim-to-real gap diagnosis", parts)


# ----------------------------------------------------------------------------- text summary


def _value(v: float, sd: float, unit: str) -> str:
    """A value with its standard deviation and unit."""
    return f"{v:.4g} ± {sd:.2g} {unit}".rstrip()


def _effect_line(entry: dict) -> str:
    """A named effect: its parameters with their uncertainty, those set by profile, its held-out shrink alone."""
    params = ", ".join(
        f"{k} = {_value(val, entry['uncertainty'][k], entry['units'].get(k, ''))}"
        for k, val in entry["parameters"].items()
    )
    prof = {k: v for k, v in entry.get("profiled_parameters", {}).items() if k != "method"}
    params += "".join(f", {k} = {val:.3g} (profiled)" for k, val in prof.items())
    sh = entry["heldout_shrink"]
    return f"  {entry['name']}: {params}" + (f" (held-out shrink alone {sh:.2f})" if sh is not None else "")


def _heldout_line(report: GapReport) -> str:
    """The held-out gap before and after the effects, and its shrink where effects explain it."""
    sh = shrink(report.gap_before, report.gap_after)
    return (
        f"held-out gap (mean z^2 - 1): before {report.gap_before.G:.3g}, after {report.gap_after.G:.3g}"
        + (f", shrink {sh:.2f}" if sh is not None and report.verdict.effects else "")
        + f" (se if no gap {report.gap_before.se:.2g})"
    )


def _rejecting_tests(report: GapReport) -> list[str]:
    """The structure tests that reject the final model (the twin's own unless effects were accepted), at the
    verdict's Bonferroni level."""
    v = report.verdict
    tests = report.where["structure_tests_after" if v.effects or v.partial else "structure_tests_before"]
    level = family_level(len(tests)) / max(len(tests), 1)  # the verdict's Bonferroni level
    bad = [t for t in tests if t["p_value"] is not None and t["p_value"] < level]
    found = "; ".join(
        f"{t['name']} ({t['channel']}, p = {t['p_value']:.1e})" + (f" at {t['at']}" if t["at"] else "") for t in bad
    )
    return [f"tests that reject the model: {found}"] if bad else []


def _untestable(report: GapReport) -> list[str]:
    """The candidates this design cannot test, and the test points that would test them or tell the ambiguous
    effects apart."""
    ident = report.identifiability
    untestable = [c for c in ident.candidates.values() if not c.identifiable]
    lines = ["not testable in this design: " + ", ".join(c.name for c in untestable)] if untestable else []
    for c in untestable + [ident.candidates[n] for n in report.verdict.ambiguous]:
        tests = sorted({s.test for p in c.params for s in p.separating if s.separates})
        if tests:
            lines.append(f"  {c.name} would be tested by: {'; '.join(tests)}")
    return lines


def _noise_line(report: GapReport) -> str:
    """The rate noise sigma0, where it comes from, and what the session states."""
    noise = report.noise
    known = [k for k, val in noise["stated_by_session"].items() if val is not None]
    return f"noise: sigma0 {noise['sigma0_radps']:.3g} rad/s ({noise['source']}); " + (
        f"stated by the session: {', '.join(known)}" if known else "nothing stated by the session (estimated)"
    )


def summary_text(report: GapReport) -> str:
    """A short human summary: verdict, effects with parameters and uncertainty, shrink, what is untestable."""
    v = report.verdict
    effects = [_effect_line(e) for e in _named_entries(report) if e["parameters"]]
    lines = [f"verdict: {v.verdict}", f"  {v.text}", *effects, _heldout_line(report)]
    lines += _rejecting_tests(report) + _untestable(report)
    lines += [_noise_line(report), f"{report.session_info['n_points']} points, {report.elapsed_s:.1f} s"]
    return "\n".join(lines)
