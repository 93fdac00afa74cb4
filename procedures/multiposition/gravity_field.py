"""What a seed-003 gravity-field session identifies: harmonics, then the coefficients with and without them.

The session holds both PIGAs' static windows as points, tagged in `extra` with the
instrument (dut A or B), the fixture setup, its pose and the block (alignment, four_pose,
calibration <scheme>), and each self-alignment's result as a measurement of kind
ALIGNMENT (the head zero the procedure applied from then on).

1. The four-pose windows of both instruments in both setups give the head's angle-error
   harmonics (four_pose.fit_four_pose).
2. Each calibration sequence of A (setup 1, pose 1) is fitted twice by the static model
   (seed 003 eqs. 43-49): at the angles the head and the self-alignment give
   (uncompensated, as seed 003 Tables 3-4), and with the identified harmonics and mounting
   offset compensated (Table 7). Eq. 49 takes the compensation as exact; the uncertainty
   of the harmonics and offset, from other windows, is also propagated (compensated_total).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from procedures.common.uncertainty import Budget, merged_json
from procedures.multiposition import budget as gum
from procedures.multiposition.four_pose import FourPoseFit, PoseWindow, fit_four_pose, harmonic_names
from procedures.multiposition.lsq import Fit
from procedures.multiposition.static_model import (
    fit_static,
    relative_fitting_accuracy_g,
    with_angle_uncertainty,
)
from station.least_squares import FitError
from station.records import Field, declare
from station.session import Session
from station.twin.fixture import pose_rad

ALIGNMENT = "self_alignment"
declare(
    ALIGNMENT,
    [Field("setup", "int64", "", lo=1), Field("round", "int64", "", lo=1),
     Field("misalignment_rad", "float64", "rad", doc="the input axis from the horizontal (seed 003 self-alignment)"),
     Field("sigma_rad", "float64", "rad", lo=0.0), Field("k0+ky_radps", "float64", "rad/s"),
     Field("zero_before_deg", "float64", "deg"), Field("zero_deg", "float64", "deg", doc="the head zero applied")],
    doc="one self-alignment round: the head zero found from the rates at 90 and 270 deg",
)  # fmt: skip
CALIBRATION = "calibration "  # block prefix, followed by the scheme
IDENTIFIABILITY = (
    "From static positions alone 1, c² and 1 − c² are linearly dependent: only k0 + ky and kzz − ky are "
    "identifiable (physics.md; vibration separates them). The fits name what they identify: k0+ky, kz, "
    "kzz-ky, koq (and k3 in physics.md's full model)."
)


@dataclass(frozen=True)
class Calibration:
    """One calibration sequence of A fitted without and with the angle-error compensation."""

    scheme: str
    positions_deg: np.ndarray
    Tm_s: np.ndarray
    uncompensated: Fit
    compensated: Fit | None  # sigma_k by eq. 49, the compensation taken as exact (as seed 003 does)
    compensated_total: Fit | None  # the same values, the harmonics' and offset's uncertainty propagated
    budgets: dict[str, Budget] = field(
        default_factory=dict
    )  # GUM budgets by fit name (procedures.multiposition.budget)

    def fits(self) -> dict[str, Fit | None]:
        return {"uncompensated": self.uncompensated, "compensated": self.compensated,
                "compensated_total": self.compensated_total}  # fmt: skip

    def to_json(self) -> dict:
        out = {"positions_deg": self.positions_deg.tolist(), "Tm_s": self.Tm_s.tolist()}
        for name, fit in self.fits().items():
            if fit is not None:
                rfa = relative_fitting_accuracy_g(fit)
                out[name] = fit.to_json() | {"max_relative_fitting_accuracy_g": float(np.max(np.abs(rfa)))}
                if name in self.budgets:
                    out[name] |= merged_json(out[name]["coefficients"], self.budgets[name], gum.TYPE_B[name])
        return out


@dataclass
class GravityFieldResult:
    terms: tuple[str, ...]
    order: int
    alignments: list[dict]
    four_pose: FourPoseFit | None
    four_pose_error: str
    calibrations: list[Calibration]
    calibration_errors: list[str] = field(default_factory=list)
    windows: list[PoseWindow] = field(default_factory=list)

    def to_json(self) -> dict:
        fp: dict = {"error": self.four_pose_error}
        if self.four_pose is not None:
            f = self.four_pose
            fp = f.fit.to_json() | {
                "harmonics_rad": {n: {"value": float(v), "sigma": float(s)} for n, v, s in
                                  zip(harmonic_names(f.order), f.harmonics_rad, f.harmonic_sigmas_rad, strict=True)},
            }  # fmt: skip
        return {
            "model_terms": list(self.terms),
            "identifiability": IDENTIFIABILITY,
            "alignment": self.alignments,
            "four_pose": fp,
            "calibration": {c.scheme: c.to_json() for c in self.calibrations},
            "calibration_errors": self.calibration_errors,
        }


def session_windows(session: Session) -> list[PoseWindow]:
    """Every static window of both instruments, in the order measured."""
    ppr = session.station.pulses_per_rev
    return [
        PoseWindow(p.extra["dut"], int(p.extra["setup"]), int(p.extra["pose"]), math.radians(p.position_deg),
                   p.measured_rate_radps(ppr), p.extra["block"], p.Tm_s)
        for p in session.points
        if p.extra.get("dut") in ("A", "B")
    ]  # fmt: skip


def final_zero_deg(session: Session, setup: int) -> float:
    """The head zero in force after the last self-alignment of a setup (0 if none)."""
    zeros = [m.values["zero_deg"] for m in session.measurements if m.kind == ALIGNMENT and m.values["setup"] == setup]
    return float(zeros[-1]) if zeros else 0.0


def final_zero_sigma_rad(session: Session, setup: int) -> float:
    """The sigma of that head zero (seed 003 eq. 56; 0 if no self-alignment)."""
    s = [m.values["sigma_rad"] for m in session.measurements if m.kind == ALIGNMENT and m.values["setup"] == setup]
    return float(s[-1]) if s else 0.0


def analyse_gravity_field(session: Session, terms: tuple[str, ...], order: int) -> GravityFieldResult:
    windows = session_windows(session)
    four = [w for w in windows if w.block == "four_pose"]
    fp, error = None, ""
    try:
        fp = fit_four_pose(four, terms, order, session.station)
    except FitError as exc:
        error = f"four-pose identification: {exc}"
    calibrations, calibration_errors = [], []
    zero_rad = math.radians(final_zero_deg(session, 1))
    for block in dict.fromkeys(w.block for w in windows if w.block.startswith(CALIBRATION)):
        cal = [w for w in windows if w.block == block]
        theta = np.array([w.theta_rad for w in cal])
        rates = np.array([w.rate_radps for w in cal])
        aligned = theta + pose_rad(cal[0].pose) + zero_rad
        try:
            unc = fit_static(aligned, rates, terms, session.station)
        except FitError as exc:
            calibration_errors.append(f"{block}: {exc}")
            continue
        comp = total = None
        tm = np.array([w.Tm_s for w in cal])
        budgets = {"uncompensated": gum.uncompensated_budget(unc, theta, aligned, rates, tm, session.station, order,
                                                             final_zero_sigma_rad(session, 1))}  # fmt: skip
        if fp is not None:
            setup = cal[0].setup
            angles = fp.instrument_angle_rad("A", setup, cal[0].pose, theta)
            comp = fit_static(angles, rates, terms, session.station)
            total = with_angle_uncertainty(comp, angles, fp.angle_derivatives(theta), fp.angle_covariance("A", setup),
                                           session.station)  # fmt: skip
            budgets["compensated_total"] = gum.compensated_budget(comp, total, fp, four, setup, cal[0].pose, theta,
                                                                  rates, tm, session.station)  # fmt: skip
        calibrations.append(Calibration(block.removeprefix(CALIBRATION), np.degrees(theta), tm, unc, comp, total,
                                        budgets))  # fmt: skip
    alignments = [m.values for m in session.measurements if m.kind == ALIGNMENT]
    return GravityFieldResult(terms, order, alignments, fp, error, calibrations, calibration_errors, windows)
