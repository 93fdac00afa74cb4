"""The calibration certificate of a seed-001 tumble session (ISO/IEC 17025 7.8; procedures.common.session_certificate).

Results: eq. 6 at each temperature block, K0 .. Mip with their GUM budget (procedures.tumble.budget) and the error
model k0 .. delta_ip = K / K1 (eq. 6, last line) with that budget carried by the chain rule; conformity of K1 and
k0 .. delta_ip against config/instruments/accelerometer-sim.toml. The environment is the chamber's product
temperature of each block (the laboratory's own is not measured); eq. 4's temperature laws stand beside as a
table of their Type A uncertainties; the stroke fit's residuals of every block, each on its own axis.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from procedures.common.certificate import NOT_MEASURED, Certificate
from procedures.common.session_certificate import Certified, MethodCard, environment_conditions, session_certificate
from procedures.tumble.analysis import EightPoint, Readings, TemperatureModel, position_deg
from procedures.tumble.report import TEMPERATURE_HEADER, block_name, temperature_rows
from station.defaults import config_file
from station.session import Session

CARD = MethodCard(
    title="Calibration certificate: pendulous accelerometer, eight-point tumble (seed 001)",
    method="eight-point tumble in the gravity field on the optical index head (seed 001 eqs. 1, 5, 6): at each "
    "temperature a least-squares stroke fit (position levels, hysteresis branch, bias drift) and eq. 6; "
    "accelerations in units of local g",
    procedure="tumble",
    procedure_title="eight-point tumble (seed 001)",
    references=("tumble_head_angle_rad", "voltmeter_gain", "voltmeter_offset_v", "chamber_temperature_c"),
    instrument_file=config_file("instruments", "accelerometer-sim.toml"),
)


RESIDUAL_CAPTION = (
    "Residuals of the stroke fit at each temperature, each block on its own axis: the readings less "
    "their position level, hysteresis branch and drift"
)


def residual_figure(r: Readings, points: list[EightPoint]):
    """The stroke fit's residuals of each temperature block on its own axis (forward and back strokes), in ug."""
    fig, axes = plt.subplots(len(points), 1, figsize=(7.5, 2.1 * len(points) + 0.4), squeeze=False)
    for ax, p in zip(axes[:, 0], points, strict=True):
        b = r.of_block(p.block)
        e_ug = p.residuals_v / p.cf[1] * 1e6
        sigma_ug = p.sigma_v / p.cf[1] * 1e6
        ax.axhspan(-sigma_ug, sigma_ug, color="0.85", label=f"±σ ({sigma_ug:.2g} µg, dof {p.dof})")
        ax.axhline(0.0, color="0.4", lw=0.6)
        for odd, label, marker in ((1, "forward strokes", "^"), (0, "back strokes", "v")):
            keep = b.stroke % 2 == odd
            ax.plot(position_deg(b.J[keep]), e_ug[keep], marker, ms=4, ls="none", label=label)
        ax.set(title=f"{block_name(p)}: residuals of the stroke fit", ylabel="e (µg)", xticks=np.arange(0, 361, 45))
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    axes[-1, 0].set_xlabel("head angle θ (deg)")
    fig.tight_layout()
    return fig


def environment(session: Session, r: Readings, points: list[EightPoint]) -> list[tuple[str, str]]:
    """The chamber's product temperature of each block (the instrument's conditions), the rest as measured."""
    rows = []
    for p in points:
        t = r.of_block(p.block).temperature_c
        rows.append((f"instrument temperature, {block_name(p)}", f"{t.mean():.2f} °C (chamber product sensor, "
                     f"{t.min():.2f} to {t.max():.2f} °C over {t.size} readings)"))  # fmt: skip
    rows.append(("laboratory temperature", f"{NOT_MEASURED} (no ambient sensor on the station)"))
    return rows + [row for row in environment_conditions(session) if row[0] != "temperature"]


def conditions(r: Readings, points: list[EightPoint]) -> list[tuple[str, str]]:
    """The tumble's conditions: the head's positions, the strokes at each temperature and the set points."""
    heads = sorted({position_deg(int(j)) for j in r.J})
    return [
        ("optical head positions", f"{len(heads)}: {', '.join(f'{x:g}' for x in heads)} deg (seed 001 Fig. 2)"),
        ("strokes", f"{int(r.stroke.max())} strokes (forward and back) at each temperature, {r.J.size} readings"),
        ("chamber set points", ", ".join(map(block_name, points))),
    ]


def _reliability(p: EightPoint) -> str:
    verdict = "no outlier" if p.mu <= p.mu_c else "POSSIBLE OUTLIER: to be reviewed"
    sigma_ug = p.sigma_v / p.cf[1] * 1e6
    return f"{block_name(p)}: σ of a reading {sigma_ug:.3g} µg ({p.dof} dof), μ {p.mu:.2f}, μc {p.mu_c:.2f}: {verdict}"


def certificate(session: Session, r: Readings, points: list[EightPoint], model: TemperatureModel) -> Certificate:
    """The certificate of the tumble session's eq. 6 results, block by block."""
    parts = []
    for p in points:
        where = f" at {block_name(p)}"
        parts.append(Certified(p.budget, suffix=where, table=f"Eq. 6{where}: K0 .. Mip (contributions |c| u)"))
        parts.append(Certified(p.error_budget(), suffix=where, table=None))
    remarks = [
        "k0, k2, k3, δo and δip are K0, K2, K3, Mo and Mip over K1 (eq. 6, last line): their budget is that of "
        "K0 .. Mip carried by the chain rule (GUM 5.1.2), so every input's correlation between them is kept.",
        "Reliability of the stroke fits (eq. 28's test on the readings): " + "; ".join(map(_reliability, points)) + ".",
        "Eq. 4's temperature laws (section 7) rest on the eq. 6 results of every block with their Type A "
        "uncertainties; their Type B inputs are those of the blocks and are not propagated again there.",
    ]
    laws = f"Temperature laws (eq. 4, T0 = {model.reference_c:g} °C; σ Type A)"
    return session_certificate(
        session,
        parts,
        CARD,
        figures=[(RESIDUAL_CAPTION, lambda: residual_figure(r, points))],
        remarks=remarks,
        environment=environment(session, r, points),
        conditions=conditions(r, points),
        extra_tables=[(laws, TEMPERATURE_HEADER, temperature_rows(model))],
    )
