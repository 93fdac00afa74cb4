"""Self-contained HTML report of a seed 001 tumble session: the seed's tables of output signals Y_JK^T, eq. 6's
coefficients at each temperature, eq. 4's temperature laws and hysteresis beside the seed's AL-15 figures, and
plots in the manner of Figs. 3 and 4 (inline SVG, no external assets).
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from procedures.common.certificate import budget_rows
from procedures.tumble.analysis import (
    POSITIONS,
    SOAK,
    EightPoint,
    Readings,
    TemperatureModel,
    TwoSlope,
    position_deg,
)
from station.htmlkit import document, mapping_table, svg, table
from station.session import Session
from station.twin.pendulous_accelerometer import CF_NAMES, AccelerometerModel

SEED = AccelerometerModel()  # the twin's defaults are the seed's AL-15 estimates
# (label, unit, scale to the unit, seed 001's value in SI or None where the seed quotes none)
ERROR_ROWS = {
    "k0": ("k0 (bias)", "mg", 1e3, SEED.k0_g),
    "k2": ("k2", "µg/g²", 1e6, SEED.k2_g_per_g2),
    "k3": ("k3", "µg/g³", 1e6, SEED.k3_g_per_g3),
    "delta_o": ("δo (base plane)", "mrad", 1e3, SEED.delta_o_rad),
    "delta_ip": ("δip", "µg/g²", 1e6, None),
}
CF_UNITS = {"K0": "V", "K1": "V/g", "K2": "V/g²", "K3": "V/g³", "Mo": "V/g", "Mip": "V/g²"}


def block_name(p: EightPoint) -> str:
    """A temperature block's name: its place in the session and its set point."""
    return f"T{p.block + 1} {p.setpoint_c:g} °C"


def pm(value: float, sigma: float, scale: float = 1.0, digits: int = 4) -> str:
    """value ± sigma in the unit that `scale` converts to."""
    return f"{value * scale:.{digits}g} ± {sigma * scale:.2g}"


def _stroke_tables(r: Readings, points: list[EightPoint]) -> str:
    parts = []
    for p in points:
        b = r.of_block(p.block)
        strokes = sorted(set(b.stroke.tolist()))
        header = ["J", "θ (deg)"] + [f"k={k} {'FS' if k % 2 else 'BS'}" for k in strokes] + ["Y_J (fit) ± σ"]
        rows = []
        for J in range(1, POSITIONS + 1):
            cells = [J, f"{position_deg(J):g}"]
            for k in strokes:
                v = b.volts[(b.J == J) & (b.stroke == k)]
                cells.append(f"{v[0]:.7f}" if v.size else "—")
            rows.append([*cells, pm(p.Y_v[J - 1], p.Y_sigma_v[J - 1], digits=8)])
        heading = f"<h3>Y_JK at {block_name(p)} (measured {p.temperature_c:.2f} °C), volts</h3>"
        parts.append(heading + table(header, rows))
    return "".join(parts)


def _cf_table(points: list[EightPoint]) -> str:
    header = ["coefficient", "unit"] + [block_name(p) for p in points]
    rows = [[n, CF_UNITS[n], *(pm(*p.coefficient(n), digits=7) for p in points)] for n in CF_NAMES]
    return table(header, rows)


def _budget_tables(points: list[EightPoint]) -> list[str]:
    """The GUM budget of eq. 6's coefficients at each temperature (procedures.tumble.budget)."""
    return [
        f"<h3>Uncertainty budget at {block_name(p)} (GUM; contributions |c| u)</h3>" + table(*budget_rows(p.budget))
        for p in points
        if p.budget is not None
    ]


def _error_table(points: list[EightPoint]) -> str:
    header = ["coefficient", "unit"] + [block_name(p) for p in points] + ["seed 001 (AL-15)"]
    rows = []
    for name, (text, unit, scale, seed) in ERROR_ROWS.items():
        seed_text = "—" if seed is None else f"{seed * scale:g}"
        rows.append([text, unit, *(pm(*p.coefficient(name), scale) for p in points), seed_text])
    rows.append(["h (hysteresis)", "mg", *(pm(*p.hysteresis_g, 1e3) for p in points), f"±{SEED.hysteresis_g * 1e3:g}"])
    rows.append(
        ["k0D (drift in the block) over 12 h", "µg", *(pm(*p.drift_g_per_s, 43200 * 1e6) for p in points), "≤ 20 (3σ)"]
    )
    rows.append(["k1 (SF instability, 3σ)", "ppm", *(f"{p.k1_3sigma_ppm:.3g}" for p in points), "15"])
    rows.append(["σ of a reading", "µg", *(f"{p.sigma_v / p.cf[1] * 1e6:.3g} (dof {p.dof})" for p in points), ""])
    rows.append(["μ vs μc", "", *(f"{p.mu:.2f} vs {p.mu_c:.2f}" for p in points), ""])
    return table(header, rows)


# Rows of the eq. 4 table: (label, unit, scale, the TwoSlope and its term, seed 001's value: SI, text or None).
LAW_ROWS = (
    ("k0N (bias at T0)", "mg", 1e3, "bias_g", "at_reference", SEED.k0_g),
    ("λT1 (bias, ΔT > 0)", "µg/°C", 1e6, "bias_g", "above", SEED.lambda_above_g_per_c),
    ("λT2 (bias, ΔT < 0)", "µg/°C", 1e6, "bias_g", "below", SEED.lambda_below_g_per_c),
    ("k0D (bias drift between temperatures) over 12 h", "µg", 43200e6, "bias_g", "drift_per_s", "≤ 20 (3σ)"),
    ("K1N (scale factor at T0)", "V/g", 1.0, "scale_factor", "at_reference", SEED.scale_v_per_g),
    ("βT1 (scale factor, ΔT > 0)", "ppm/°C", 1e6, "scale_factor", "above", SEED.beta_above_per_c),
    ("βT2 (scale factor, ΔT < 0)", "ppm/°C", 1e6, "scale_factor", "below", SEED.beta_below_per_c),
    ("δoN (base plane at T0)", "mrad", 1e3, "misalignment_rad", "at_reference", SEED.delta_o_rad),
    ("γT1 (base plane, ΔT > 0)", "µrad/°C", 1e6, "misalignment_rad", "above", None),
    ("γT2 (base plane, ΔT < 0)", "µrad/°C", 1e6, "misalignment_rad", "below", None),
)


TEMPERATURE_HEADER = ("coefficient (eq. 4)", "unit", "estimate ± σ", "seed 001 (AL-15)")


def temperature_rows(model: TemperatureModel) -> list[list[str]]:
    """Eq. 4's laws and the hysteresis: label, unit, estimate ± sigma (or why there is none), the seed's figure."""
    rows = []
    for text, unit, scale, law, term, seed in LAW_ROWS:
        pair: tuple[float, float] | None = getattr(getattr(model, law), term)
        estimate = "not separable by this session" if pair is None else pm(*pair, scale)
        quoted = seed if isinstance(seed, str) else "—" if seed is None else f"{seed * scale:g}"
        rows.append([text, unit, estimate, quoted])
    rows.append(["h_T (hysteresis, all temperatures)", "mg", pm(*model.hysteresis_g, 1e3),
                 f"±{SEED.hysteresis_g * 1e3:g}"])  # fmt: skip
    return rows


def _law_curve(law: TwoSlope, dT: np.ndarray, relative: bool = False) -> np.ndarray:
    above = law.above[0] if law.above else 0.0
    below = law.below[0] if law.below else 0.0
    slope = np.where(dT > 0, above, below) * dT
    return law.at_reference[0] * (1 + slope) if relative else law.at_reference[0] + slope


def _temperature_plots(points: list[EightPoint], model: TemperatureModel) -> str:
    """Seed 001 Fig. 3: the bias with its hysteresis band (a) and the scale factor (b) against dT."""
    dT = np.array([p.temperature_c - model.reference_c for p in points])
    grid = np.linspace(min(dT.min(), 0.0) - 5, max(dT.max(), 0.0) + 5, 200)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    k0 = np.array([p.coefficient("k0") for p in points])
    h = model.hysteresis_g[0]
    curve = _law_curve(model.bias_g, grid)
    a.fill_between(grid, (curve - h) * 1e3, (curve + h) * 1e3, alpha=0.2, label="± h (hysteresis)")
    a.plot(grid, curve * 1e3, label="eq. 4 fit")
    a.errorbar(dT, k0[:, 0] * 1e3, yerr=3e3 * k0[:, 1], fmt="o", label="eq. 6 (3σ)")
    a.set(title="(a) bias k0(ΔT)", xlabel="ΔT (°C)", ylabel="mg")
    k1 = np.array([p.coefficient("K1") for p in points])
    k1n = model.scale_factor.at_reference[0]
    b.plot(grid, (_law_curve(model.scale_factor, grid, relative=True) / k1n - 1) * 1e6, label="eq. 4 fit")
    b.errorbar(dT, (k1[:, 0] / k1n - 1) * 1e6, yerr=3e6 * k1[:, 1] / k1n, fmt="o", label="eq. 6 (3σ)")
    b.set(title="(b) scale factor K1(ΔT) / K1N - 1", xlabel="ΔT (°C)", ylabel="ppm")
    for ax in (a, b):
        ax.grid(alpha=0.3)
        ax.legend()
    return svg(fig)


def _stroke_plots(r: Readings, points: list[EightPoint]) -> str:
    """Each reading less its position level, by stroke direction: the hysteresis loop, and the drift."""
    fig, axes = plt.subplots(1, len(points), figsize=(4 * len(points) + 1, 3.6), squeeze=False)
    for ax, p in zip(axes[0], points, strict=True):
        b = r.of_block(p.block)
        dev_ug = (b.volts - p.Y_v[b.J - 1]) / p.cf[1] * 1e6
        for odd, label, marker in ((1, "forward", "^"), (0, "back", "v")):
            keep = b.stroke % 2 == odd
            ax.plot(position_deg(b.J[keep]), dev_ug[keep], marker, label=f"{label} strokes", alpha=0.7)
        ax.set(title=f"{block_name(p)}: y - Y_J", xlabel="θ (deg)", ylabel="µg", xticks=np.arange(0, 361, 90))
        ax.grid(alpha=0.3)
        ax.legend()
    return svg(fig)


def _chamber_plot(session: Session, r: Readings) -> str:
    """Seed 001 Fig. 4 (b, d): the temperature over the session."""
    fig, ax = plt.subplots(figsize=(11, 3.2))
    for m in session.measurements:
        if m.kind == SOAK:
            ax.plot(m.arrays["t_s"] / 3600, m.arrays["temperature_c"], "-", color="C0")
    ax.plot(r.t_s / 3600, r.temperature_c, ".", color="C1", label="at each reading")
    ax.set(title="Chamber product temperature", xlabel="station time (h)", ylabel="°C")
    ax.grid(alpha=0.3)
    ax.legend()
    return svg(fig)


def render_tumble_report(
    session: Session, r: Readings, points: list[EightPoint], model: TemperatureModel, *, title: str
) -> str:
    """The whole report as one HTML string."""
    parts = [
        f"<p>{r.volts.size} readings at {len(points)} temperatures; T0 = {model.reference_c:g} °C. "
        "Accelerations in units of local g. Seed column: the AL-15 figures of seed 001 (— where it quotes none).</p>",
        "<h2>Error model at each temperature (eq. 6, last line; hysteresis and drift of eqs. 3-4)</h2>",
        _error_table(points),
        "<h2>Temperature laws (eq. 4)</h2>",
        table(TEMPERATURE_HEADER, temperature_rows(model)),
        _temperature_plots(points, model),
        "<h2>Conversion function coefficients (eq. 1 by eq. 6)</h2>",
        _cf_table(points),
        *_budget_tables(points),
        "<h2>Hysteresis and drift: readings less their position level</h2>",
        _stroke_plots(r, points),
        _chamber_plot(session, r),
        "<h2>Output signals Y_JK^T (the seed's tables)</h2>",
        _stroke_tables(r, points),
        "<h2>Station</h2>" + mapping_table(vars(session.station)),
    ]
    return document(title, parts)


def summary(points: list[EightPoint], model: TemperatureModel) -> str:
    """A few lines for the console."""

    def line(name: str, pair: tuple[float, float] | None, scale: float, unit: str) -> str:
        return f"{name} = {'n/a' if pair is None else pm(*pair, scale)} {unit}"

    lines = []
    for p in points:
        k = {n: p.coefficient(n) for n in ("k0", "k2", "k3", "delta_o")}
        lines.append(
            f"{block_name(p)}: "
            + ", ".join(
                [
                    line("k0", k["k0"], 1e3, "mg"),
                    line("k2", k["k2"], 1e6, "ug/g2"),
                    line("k3", k["k3"], 1e6, "ug/g3"),
                    line("do", k["delta_o"], 1e3, "mrad"),
                    line("h", p.hysteresis_g, 1e3, "mg"),
                    f"k1 = {p.k1_3sigma_ppm:.3g} ppm (3 sigma)",
                ]
            )
        )
    m = model
    lines.append(
        ", ".join(
            [
                line("lambda_T1", m.bias_g.above, 1e6, "ug/C"),
                line("lambda_T2", m.bias_g.below, 1e6, "ug/C"),
                line("beta_T1", m.scale_factor.above, 1e6, "ppm/C"),
                line("beta_T2", m.scale_factor.below, 1e6, "ppm/C"),
                line("gamma_T1", m.misalignment_rad.above, 1e6, "urad/C"),
                line("gamma_T2", m.misalignment_rad.below, 1e6, "urad/C"),
                line("h_T", m.hysteresis_g, 1e3, "mg"),
            ]
        )
    )
    return "\n".join(lines)
