"""The calibration certificate of a seed-004 suppression session (ISO/IEC 17025 7.8;
procedures.common.session_certificate).

Results: K2 = kzz / kz at the best offset and after the mass removal, and the mass removed at each of the four
points (eqs. 21-22), with their one GUM budget (procedures.nonlinear_suppression.budget: the two calibrations'
seed-000 inputs
shared, H, b and theta for the mass); K2 against config/instruments/piga-suppressed-sim.toml. The offset sweep
(Fig. 10) and the two calibrations' residuals (seed 000 eq. 21, each on its own axis) are the figures.
"""

from __future__ import annotations

from procedures.common.certificate import Certificate, TableText
from procedures.common.session_certificate import Certified, MethodCard, session_certificate
from procedures.integral_precession.budget import SEED000_REFERENCES
from procedures.integral_precession.identify import identify
from procedures.integral_precession.report import residual_figure
from procedures.nonlinear_suppression.analysis import SEED004_TYPE_B, Suppression, sweep_figure
from procedures.nonlinear_suppression.budget import calibration_points
from station.defaults import config_file
from station.session import Session

CARD = MethodCard(
    title="Calibration certificate: PIGA quadratic term after suppression (seed 004)",
    method="suppression of the quadratic term (seed 004): a sweep of the angle servo's digital offset, K2 = kzz / kz "
    "of each offset by integral precession (seed 000 eqs. 19-22), a cubic spline and line search for the best "
    "offset (section 5.1), the inertia-product correction by mass removal (eqs. 21-22, section 5.2) and the "
    "calibration after it",
    procedure="nonlinear_suppression",
    procedure_title="suppression of the quadratic term (seed 004)",
    references=(*SEED000_REFERENCES, "angular_momentum_kgm2ps", "end_radius_mm", "removal_angle_deg"),
    instrument_file=config_file("instruments", "piga-suppressed-sim.toml"),
)
SWEEP_CAPTION = "K2 against the digital offset: the sweep, its spline and minimum, and the two calibrations (Fig. 10)"
RESIDUAL_CAPTION = ("Residuals of Y (seed 000 eq. 21) of the calibrations at the best offset and after the mass "
                    "removal, each on its own axis, and their proportional residuals (eq. 29)")  # fmt: skip


def _correction_table(s: Suppression) -> list[TableText]:
    c = s.correction
    if c is None:
        return []
    fit = s.sweep
    rows = [
        ("K2 calibrated at the best offset (1/g0)", f"{c.k2_per_g:.3e}"),
        (
            "inertia product J_X2Z2 (kg m², eq. 21)",
            f"{c.inertia_product_kgm2:.4e} ± {c.sigma_inertia_product_kgm2:.1e}",
        ),
        ("H (kg m²/s), b (mm), θ (deg)", f"{c.angular_momentum_kgm2ps:g}, {c.radius_mm:g}, {c.angle_deg:g}"),
        (
            'best offset, spline and line search (")',
            f"{fit.best_offset_arcsec:+.3f} ± {fit.sigma_best_offset_arcsec:.3f}",
        ),
    ]
    return [("Inertia-product correction (seed 004 eqs. 21-22; ± σ Type A)", ("quantity", "value"), rows)]


def certificate(session: Session, s: Suppression) -> Certificate | None:
    """The certificate of the session's headline figures (None when it has neither calibration that carries them)."""
    if s.budget is None:
        return None
    cals = {c.stage: identify(Session(session.station, calibration_points(session, c))) for c in (s.at_best, s.after)
            if c is not None}  # fmt: skip
    pooled = [f"{c.stage}: {c.n_points} points, rate noise pooled over {c.noise_dof or c.dof} dof"
              for c in (s.at_best, s.after) if c is not None]  # fmt: skip
    remarks = [
        SEED004_TYPE_B + ".",
        "Calibrations: " + "; ".join(pooled) + ". Both see the same station, so their shared Type B inputs stay "
        "correlated in the covariance of the results JSON.",
        "The removed mass is an adjustment made on the instrument, not a property it must meet: it has no limit.",
    ]
    return session_certificate(
        session,
        [Certified(s.budget, table="K2 and removed mass (contributions |c| u)",
                   limit_names={"K2_at_best": "K2", "K2_after_removal": "K2"})],
        CARD,
        figures=[(SWEEP_CAPTION, lambda: sweep_figure(s)), (RESIDUAL_CAPTION, lambda: residual_figure(cals))],
        remarks=remarks,
        extra_tables=_correction_table(s),
    )  # fmt: skip
