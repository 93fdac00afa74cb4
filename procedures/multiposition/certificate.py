"""The calibration certificate of a seed-003 gravity-field session (ISO/IEC 17025 7.8;
procedures.common.session_certificate).

Results: PIGA A's static coefficients (k0+ky, kz, kzz-ky, koq) of each calibration sequence, without the angle-error
compensation (Tables 3-4; the head's harmonics as Type B inputs of its stated accuracy) and with it (Table 7; the
harmonics and mounting offset of the four-pose method as a Type A block), each with its GUM budget
(procedures.multiposition.budget) and against config/instruments/piga-sim.toml. The four-pose harmonics (Table 6) and
the
self-alignments stand beside; the residuals of every fit on its own axis.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from procedures.common.certificate import Certificate, TableText
from procedures.common.session_certificate import Certified, MethodCard, session_certificate
from procedures.multiposition.budget import TYPE_B
from procedures.multiposition.four_pose import harmonic_names
from procedures.multiposition.gravity_field import IDENTIFIABILITY, GravityFieldResult
from procedures.multiposition.static_model import relative_fitting_accuracy_g
from station.session import Session

ARCSEC_PER_RAD = 180 / np.pi * 3600
CARD = MethodCard(
    title="Calibration certificate: PIGA static coefficients in the gravity field (seed 003)",
    method="static calibration of PIGA A in the gravity field on the indexing head (seed 003 eqs. 14, 43-49), "
    "without and with the head's angle-error harmonics compensated; the harmonics and mounting offsets by the "
    "orthogonal four-pose method with PIGA B on the same fixture (eqs. 16-42, one least squares); head zero by "
    "the self-alignment (eqs. 52-56)",
    procedure="multiposition",
    procedure_title="gravity field on the indexing head (seed 003)",
    references=("index_harmonic_rad", "latitude_deg", "timer_resolution_s"),
)
FITS = {"uncompensated": "without compensation", "compensated_total": "with compensation"}
RESIDUAL_CAPTION = ("Relative fitting accuracy e / kz of A's static fit at each position (seed 003 Figs. 10-11), "
                    "each sequence without and with the compensation on its own axis")  # fmt: skip


def residual_figure(res: GravityFieldResult):
    """e / kz (ug) per position of every calibration fit; uncompensated and compensated on their own axes."""
    cals = res.calibrations
    fig, axes = plt.subplots(len(cals), 2, figsize=(7.5, 2.4 * len(cals) + 0.4), squeeze=False)
    for row, cal in zip(axes, cals, strict=True):
        for ax, (name, fit) in zip(row, (("uncompensated", cal.uncompensated), ("compensated", cal.compensated)),
                                   strict=True):  # fmt: skip
            if fit is None:
                ax.set_axis_off()
                ax.text(0.5, 0.5, "no four-pose result:\nnot compensated", ha="center", va="center", fontsize=8)
                continue
            rfa_ug = relative_fitting_accuracy_g(fit) * 1e6
            sigma_ug = fit.sigma_residual / fit.value("kz")[0] * 1e6
            ax.axhspan(-sigma_ug, sigma_ug, color="0.85", label="±σ of the fit")
            ax.axhline(0.0, color="0.4", lw=0.6)
            ax.plot(cal.positions_deg % 360, rfa_ug, "o", ms=3.5, label="e / kz at each position")
            ax.set(title=f"{cal.scheme}, {name}", xlabel="head angle (deg)", ylabel="µg", xticks=np.arange(0, 361, 90))
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=8)
    handles, labels = next(ax for ax in axes.flat if ax.axison).get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.35 / fig.get_size_inches()[1]))
    return fig


def _tables(res: GravityFieldResult) -> list[TableText]:
    out: list[TableText] = []
    fp = res.four_pose
    if fp is not None:
        rows = [
            (n, f"{v:.4e}", f"{s:.1e}", f"{v * ARCSEC_PER_RAD:.3f}", f"{s * ARCSEC_PER_RAD:.3f}")
            for n, v, s in zip(harmonic_names(fp.order), fp.harmonics_rad, fp.harmonic_sigmas_rad, strict=True)
        ]
        out.append((f"Angle-error harmonics of the head by the four-pose method (Table 6; {fp.fit.dof} dof)",
                    ("harmonic", "value (rad)", "σ (rad)", "value (″)", "σ (″)"), rows))  # fmt: skip
    align = [(a["setup"], a["round"], f"{a['misalignment_rad']:.3e}", f"{a['sigma_rad']:.1e}", f"{a['zero_deg']:.6f}")
             for a in res.alignments]  # fmt: skip
    if align:
        out.append(("Self-alignment (eqs. 52-56)", ("setup", "round", "θ0 (rad)", "σ (rad)", "head zero (deg)"), align))
    return out


def certificate(session: Session, res: GravityFieldResult) -> Certificate | None:
    """The certificate of A's calibration sequences (None when the session has none)."""
    parts = [Certified(cal.budgets[name], suffix=f" ({cal.scheme}, {text})",
                       table=f"{cal.scheme}, {len(cal.positions_deg)} positions, {text} (contributions |c| u)")
             for cal in res.calibrations for name, text in FITS.items() if name in cal.budgets]  # fmt: skip
    if not parts:
        return None
    fits = [
        f"{cal.scheme} {name}: σ residual {fit.sigma_residual:.2e} rad/s, {fit.dof} dof"
        for cal in res.calibrations
        for name, fit in cal.fits().items()
        if fit and name != "compensated_total"
    ]
    remarks = [IDENTIFIABILITY, f"Without compensation: {TYPE_B['uncompensated']}. With compensation: "
               f"{TYPE_B['compensated_total']}.", f"Fits: {'; '.join(fits)}.", *res.calibration_errors]  # fmt: skip
    if res.four_pose is None:
        remarks.append(f"No compensated result: {res.four_pose_error}")
    return session_certificate(
        session,
        parts,
        CARD,
        figures=[(RESIDUAL_CAPTION, lambda: residual_figure(res))],
        remarks=remarks,
        identification=[("second instrument", "PIGA B on the same fixture (seed 003 Fig. 3): its windows enter the "
                                              "four-pose method only; it is not calibrated by this certificate")],
        extra_tables=_tables(res),
    )  # fmt: skip
