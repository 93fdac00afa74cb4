"""The calibration certificate of a seed-002 session (ISO/IEC 17025 7.8; procedures.common.session_certificate).

Results: the twelve flexure coefficients tau_ijk of eq. 21 in arcsec/g with their GUM budget
(procedures.rlg_g_sensitivity.budget), each against the one limit of config/instruments/imu-sim.toml; the residuals
of eq. 21
run by run (east and north each on its own axis, with the sigma its weight gives it); the verification runs'
velocity errors (seed 002 section 4, Table 2) beside.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from procedures.common.certificate import Certificate
from procedures.common.session_certificate import Certified, MethodCard, session_certificate
from procedures.common.uncertainty import Budget
from procedures.rlg_g_sensitivity.analysis import FlexureFit, run_weights
from procedures.rlg_g_sensitivity.budget import SEED002_TYPE_B
from station.defaults import config_file
from station.session import Measurement, Session
from station.twin.strapdown_imu import ARCSEC_RAD, TAU_NAMES

CARD = MethodCard(
    title="Calibration certificate: g-sensitive misalignments of a strapdown IMU's gyros (seed 002)",
    method="g-sensitive misalignment of the gyro triad in linear vibration (seed 002 eqs. 15-22): per fixture pose "
    "a static alignment, sine vibration in inertial navigation and a static realignment, reduced to the "
    "attitude-error observation; eq. 21 by least squares weighted by the reduction's noise",
    procedure="rlg_g_sensitivity",
    procedure_title="g-sensitive misalignment (seed 002)",
    references=("imu_accel_scale", "imu_gyro_bias_radps", "imu_clock_rel", "latitude_deg", "imu_gyro_scale"),
    instrument_file=config_file("instruments", "imu-sim.toml"),
)
VERIFY_HEADER = ("run", "vibration", "pose", "|δv| end, uncompensated (m/s)", "|δv| end, compensated (m/s)",
                 "from σ(τ) alone (m/s)", "decrease %")  # fmt: skip
RESIDUAL_CAPTION = ("Residuals B - A tau of eq. 21 per calibration run, east and north each on its own axis; the "
                    "band is the sigma of one component at its weight")  # fmt: skip


def verification_rows(checks: list[dict]) -> list[tuple]:
    """The verification runs' velocity errors without and with compensation (Table 2), as VERIFY_HEADER (the
    report's table too)."""
    return [(c["key"], c["mode"], c["pose"], f"{c['v_end_uncompensated_mps']:.4f}", f"{c['v_end_compensated_mps']:.4f}",
             f"{c['predicted_sigma_mps']:.4f}", f"{c['decrease_pct']:.1f}") for c in checks]  # fmt: skip


def residual_figure(runs: list[Measurement], fit: FlexureFit):
    """Eq. 21's residuals per run, east and north on their own axes, in arcsec, with +-sigma at each weight."""
    e = fit.residuals.reshape(-1, 2) / ARCSEC_RAD
    sigma = fit.sigma_residual / ARCSEC_RAD / np.sqrt(run_weights([m.values for m in runs]).reshape(-1, 2))
    x = np.arange(1, len(runs) + 1)
    fig, axes = plt.subplots(2, 1, figsize=(7.5, 4.6), sharex=True)
    for k, (ax, name) in enumerate(zip(axes, ("east", "north"), strict=True)):
        ax.fill_between(x, -sigma[:, k], sigma[:, k], step="mid", color="0.85", label="±σ at its weight")
        ax.axhline(0.0, color="0.4", lw=0.6)
        ax.plot(x, e[:, k], "o", ms=4, label=f"{name} residual")
        ax.set(ylabel="arcsec", title=f"eq. 21 residuals, {name} component ({fit.dof} dof)")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    axes[1].set_xticks(x, [m.key for m in runs], rotation=30, ha="right", fontsize=7)
    axes[1].set_xlabel("calibration run")
    fig.tight_layout()
    return fig


def certificate(session: Session, fit: FlexureFit, budget: Budget, runs: list[Measurement],
                checks: list[dict]) -> Certificate:  # fmt: skip
    """The certificate of the session's flexure coefficients (eq. 21) and its verification runs."""
    remarks = [
        f"Eq. 21 over {len(runs)} calibration runs ({2 * len(runs)} observations for {len(TAU_NAMES)} "
        f"coefficients): residual σ {fit.sigma_residual / ARCSEC_RAD:.3f} arcsec (north; east at its weight), "
        f"{fit.dof} degrees of freedom, condition number of A {fit.condition:.2f}.",
        SEED002_TYPE_B + ".",
    ]
    extra = [("Verification: velocity error without and with compensation (seed 002 section 4, Table 2)",
              VERIFY_HEADER, verification_rows(checks))] if checks else []  # fmt: skip
    table = "Eq. 21 (contributions |c| u in arcsec/g)"
    return session_certificate(
        session,
        [Certified(budget, prefix="tau_", table=table, limit_names=dict.fromkeys(TAU_NAMES, "tau"))],
        CARD,
        figures=[(RESIDUAL_CAPTION, lambda: residual_figure(runs, fit))],
        remarks=remarks,
        extra_tables=extra,
    )
