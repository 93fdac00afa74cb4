"""Seed 004: suppression of the PIGA's quadratic term by the angle servo's digital offset and a mass removal.

`nonlinear_suppression` (seed 004 section 5): the digital offset of the angle servo in the PIGA's
electronics (drivers.piga_electronics.driver) is stepped over the sweep (-5" to 5" in 0.5" steps by default), and at
each step the quadratic term is calibrated by integral precession on the vibration table (seed 000: a few
positions at three frequencies and a static test each, short windows). A cubic spline through K2(offset) and a
line search give the best offset (5.1); the servo is set there and K2 is calibrated again with longer windows,
which gives the float's inertia product (eq. 21) and the mass to remove at four points (eq. 22). The operator has
the mass removed and the instrument remounted (5.2); a last calibration at the best offset shows what is left.

The default calibration per step, 0, 180 and 60 deg at 8, 9 and 10 Hz plus static with 60 s windows (12 points,
5 degrees of freedom left; 13.7 min of station time by the dry run), identifies kzz to about 3.5e-8 rad/s/g^2,
K2 to about 6e-8/g0 (the seed's centrifuge: 1e-7/g0): fine enough for a curve that rises from 3.7e-7/g0 to
1.9e-6/g0 within 0.85". The dry run of the default file: 4.8 h for the sweep, 50 min for each calibration at the
best offset, 4 h (an estimate) for the operator to remove the mass and remount the PIGA; 10.4 h in all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from procedures.common.session_certificate import issue_certificate, result_provenance, session_uid
from procedures.nonlinear_suppression import analysis
from procedures.nonlinear_suppression.budget import with_budget
from procedures.nonlinear_suppression.certificate import certificate
from station.engine.params import Param
from station.engine.registry import Analysis, procedure
from station.engine.steps import Checkpoint, MeasurePoint, Note, OperatorAction, Step
from station.records import Field, declare
from station.session import Measurement, PointRecord, Session
from station.twin.nonlinear_error import ANGULAR_MOMENTUM_KGM2PS, END_RADIUS_M, MASS_REMOVAL
from station.twin.plan import multiposition_plan, point_id

if TYPE_CHECKING:
    from station.engine.context import PlanContext, RunContext

ELECTRONICS = "piga_electronics"  # drivers.piga_electronics.driver.DEVICE_KIND.name
SWEEP_FIT_KIND = "offset_sweep_fit"
CORRECTION_KIND = "inertia_product_correction"
declare(
    "mass_removal",
    [Field("mass_mg", "float64", "mg", lo=0.0), Field("radius_mm", "float64", "mm", lo=0.0),
     Field("angle_deg", "float64", "deg")],
    doc="the operator's mass removal from the float (seed 004 section 5.2)",
)  # fmt: skip
declare(
    SWEEP_FIT_KIND,
    [Field(n, "float64", u) for n, u in (("best_offset_arcsec", "arcsec"), ("sigma_best_offset_arcsec", "arcsec"),
                                         ("k2_min_per_g", "1/g"), ("sigma_k2_min_per_g", "1/g"),
                                         ("sample_best_offset_arcsec", "arcsec"), ("sample_k2_min_per_g", "1/g"))],
    arrays=[Field("offsets_arcsec", "float64", "arcsec"), Field("k2_per_g", "float64", "1/g"),
            Field("sigma_k2_per_g", "float64", "1/g")],
    doc="K2 at every offset of the sweep, its spline and minimum (seed 004 section 5.1)",
)  # fmt: skip
declare(
    CORRECTION_KIND,
    [Field(n, "float64", u) for n, u in (("k2_per_g", "1/g"), ("inertia_product_kgm2", "kg m^2"),
                                         ("sigma_inertia_product_kgm2", "kg m^2"), ("mass_mg", "mg"),
                                         ("sigma_mass_mg", "mg"), ("angular_momentum_kgm2ps", "kg m^2/s"),
                                         ("radius_mm", "mm"), ("angle_deg", "deg"))],
    doc="J_X2Z2 and the mass that takes it away (seed 004 eqs. 21-22)",
)  # fmt: skip
REMOUNT_S = 4 * 3600.0  # dismount, laser fine-weight adjustment, reassembly and remounting
SEED004_OFFSETS_ARCSEC = [round(-5.0 + 0.5 * i, 1) for i in range(21)]  # section 5.1: -5" to 5" by 0.5"


def sweep_prefix(index: int) -> str:
    """The calibration group of the index-th offset of the sweep: S01, S02, ..."""
    return f"S{index + 1:02d}"


PARAMS = (
    Param("offsets_arcsec", list, default=SEED004_OFFSETS_ARCSEC, min=-60.0, max=60.0, unit="arcsec",
          help="digital offsets of the angle servo to calibrate K2 at (seed 004: -5 to 5 by 0.5)"),
    Param("positions_deg", list, default=[0.0, 180.0, 60.0], min=-360.0, max=360.0, unit="deg",
          help="indexing positions of each calibration"),
    Param("freqs_hz", list, default=[8.0, 9.0, 10.0], min=0.1, max=10.0, unit="Hz",
          help="vibration frequencies at every position (each position also gets a static test)"),
    Param("window_s", float, default=60.0, min=1.0, max=100_000.0, unit="s",
          help="target window length of the sweep's calibrations"),
    Param("verify_window_s", float, default=240.0, min=1.0, max=100_000.0, unit="s",
          help="target window length of the calibrations at the best offset"),
    Param("settle_s", float, default=2.0, min=0.0, max=600.0, unit="s", help="settling after each change"),
    Param("angular_momentum_kgm2ps", float, default=ANGULAR_MOMENTUM_KGM2PS, min=1e-4, max=10.0, unit="kg m^2/s",
          help="the rotor's angular momentum H (instrument design data; eq. 21)"),
    Param("end_radius_mm", float, default=END_RADIUS_M * 1e3, min=1.0, max=100.0, unit="mm",
          help="radius r_f of the float's end surfaces, where the mass is removed (eq. 22)"),
    Param("removal_angle_deg", float, default=45.0, min=1.0, max=89.0, unit="deg",
          help="angle between the removal points and the pendulous mass (seed 004: 45)"),
    Param("remove_mass", bool, default=True, help="have the mass removed and calibrate once more after it"),
)  # fmt: skip


@dataclass(frozen=True)
class SetServoOffset(Step):
    """Set the angle servo's digital offset and wait for lock. Result: the offset in force (arcsec).

    It records nothing, so that a resumed session sets the offset again before the points that follow.
    """

    offset_arcsec: float

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        section = ctx.require(ELECTRONICS)
        limit = section.offset_max_arcsec
        if not (math.isfinite(self.offset_arcsec) and abs(self.offset_arcsec) <= limit):
            raise ctx.fail("offset_arcsec", self.offset_arcsec, f"-{limit:g} .. {limit:g} arcsec ([{ELECTRONICS}])")
        ctx.state.devices[ELECTRONICS] = {"offset_arcsec": self.offset_arcsec}
        return section.servo_settle_s, self.offset_arcsec

    def run(self, ctx: RunContext) -> float:
        electronics = ctx.hw.device(ELECTRONICS)
        offset = electronics.set_offset_arcsec(self.offset_arcsec)
        electronics.wait_locked()
        return offset


@dataclass(frozen=True)
class RecordServoOffset(Step):
    """Read back the offset in force and the servo's state before a calibration group. Result: a Measurement."""

    name: str
    prefix: str  # the calibration group that follows
    stage: str

    @property
    def key(self) -> str:
        return self.name

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        ctx.require(ELECTRONICS)
        offset = ctx.state.devices.get(ELECTRONICS, {}).get("offset_arcsec", 0.0)
        return 0.0, analysis.servo_offset_measurement(
            self.key, self.prefix, self.stage, offset, servo="LOCK", beta_error_arcsec=0.0
        )

    def run(self, ctx: RunContext) -> Measurement:
        electronics = ctx.hw.device(ELECTRONICS)
        status = electronics.servo_status()
        return analysis.servo_offset_measurement(
            self.key,
            self.prefix,
            self.stage,
            electronics.offset_arcsec(),
            servo=status.state,
            beta_error_arcsec=status.beta_error_arcsec,
        )


@dataclass(frozen=True)
class RemoveMass(OperatorAction):
    """The operator's mass removal (section 5.2), recorded, so that a resumed session never asks for it twice."""

    name: str = "mass-removal"

    @property
    def key(self) -> str:
        return self.name

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        expected_s, _ = super().plan(ctx)
        return expected_s, Measurement(self.key, "mass_removal", dict(self.action)[MASS_REMOVAL])

    def run(self, ctx: RunContext) -> Measurement:
        super().run(ctx)
        return Measurement(self.key, "mass_removal", dict(self.action)[MASS_REMOVAL])


def set_and_record(prefix: str, stage: str, offset_arcsec: float):
    """Set the offset, then record it for the calibration group `prefix`; the procedure receives the record."""
    yield SetServoOffset(offset_arcsec)
    return (yield RecordServoOffset(f"{prefix}-offset", prefix, stage))


@dataclass(frozen=True)
class FitSweep(Step):
    """K2 at every offset of the sweep, the spline and its minimum (section 5.1). Result: a Measurement."""

    name: str
    offsets_arcsec: tuple[float, ...]
    groups: tuple[tuple[PointRecord, ...], ...]  # the calibration at each offset
    positions_deg: tuple[float, ...]
    freqs_hz: tuple[float, ...]

    @property
    def key(self) -> str:
        return self.name

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        defect = analysis.design_defect(ctx.model.station, self.positions_deg, self.freqs_hz)
        if defect:
            raise ctx.fail("positions_deg, freqs_hz", (self.positions_deg, self.freqs_hz), defect)
        if len(set(self.offsets_arcsec)) < 4 or len(set(self.offsets_arcsec)) != len(self.offsets_arcsec):
            raise ctx.fail("offsets_arcsec", list(self.offsets_arcsec), "at least 4 offsets, each once (a spline)")
        mid = float(np.median(self.offsets_arcsec))
        return 0.0, self._measurement(
            analysis.SweepFit(np.array(self.offsets_arcsec), np.zeros(0), np.zeros(0), mid, 0.0, 0.0, 0.0, mid, 0.0)
        )

    def run(self, ctx: RunContext) -> Measurement:
        cals = analysis.pooled(
            [
                analysis.calibrate(ctx.hw.station, g, sweep_prefix(i), analysis.SWEEP, x)
                for i, (g, x) in enumerate(zip(self.groups, self.offsets_arcsec, strict=True))
            ]
        )
        fit = analysis.fit_sweep(self.offsets_arcsec, [c.k2_per_g for c in cals], [c.sigma_k2_per_g for c in cals])
        return self._measurement(fit)

    def _measurement(self, fit: analysis.SweepFit) -> Measurement:
        values = {k: v for k, v in fit.to_json().items() if not isinstance(v, list)}
        arrays = {k: np.asarray(v) for k, v in fit.to_json().items() if isinstance(v, list)}
        return Measurement(self.key, SWEEP_FIT_KIND, values, arrays)


@dataclass(frozen=True)
class InertiaProductCorrection(Step):
    """J_X2Z2 and the mass to remove from K2 calibrated at the best offset (eqs. 21-22). Result: a Measurement."""

    name: str
    points: tuple[PointRecord, ...]
    offset_arcsec: float
    angular_momentum_kgm2ps: float
    radius_mm: float
    angle_deg: float

    @property
    def key(self) -> str:
        return self.name

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        nominal = analysis.Correction(0.0, 0.0, 0.0, 0.0, 0.0, self.angular_momentum_kgm2ps, self.radius_mm,
                                      self.angle_deg)  # fmt: skip
        return 0.0, Measurement(self.key, CORRECTION_KIND, vars(nominal).copy())

    def run(self, ctx: RunContext) -> Measurement:
        cal = analysis.calibrate(ctx.hw.station, self.points, "B", analysis.AT_BEST, self.offset_arcsec)
        corr = analysis.correction(cal, self.angular_momentum_kgm2ps, self.radius_mm, self.angle_deg)
        return Measurement(self.key, CORRECTION_KIND, vars(corr).copy())


def calibration(prefix: str, p: dict, window_s: float):
    """One integral precession calibration: its points; the procedure receives their records."""
    records = []
    for i, spec in enumerate(multiposition_plan(p["positions_deg"], p["freqs_hz"], window_s)):
        records.append(
            (
                yield MeasurePoint(
                    f"{prefix}-{point_id(i, spec)}", spec.position_deg, spec.freq_hz, spec.preset_pulses, p["settle_s"]
                )
            )
        )
    return tuple(records)


def analyse_suppression(session: Session) -> Analysis:
    """The sweep, the correction and the verification from the stored session, its report and certificate."""
    s = with_budget(session, analysis.suppression(session))
    uid = session_uid(session)
    title = f"Session {uid}: suppression of the quadratic term (seed 004)"
    results = {
        "suppression": {
            "headline": s.headline(),
            "gum": s.gum(),
            "seed004": analysis.SEED_FIGURES,
            "sweep": s.sweep.to_json(),
            "correction": vars(s.correction) if s.correction else None,
            "calibrations": [c.to_json() for c in s.calibrations],
        }
    }
    results["suppression"]["provenance"] = result_provenance(session)
    files, why_not = issue_certificate(lambda: certificate(session, s), uid)
    if not files and not why_not:
        why_not = "no certificate: no calibration at the best offset or after"
    summary = "\n".join(filter(None, [analysis.summary(s), why_not]))
    return Analysis(results, analysis.report_html(s, title), summary, files)


@procedure(
    "nonlinear_suppression",
    "Suppression of the quadratic term: servo offset sweep, inertia-product correction (seed 004)",
    PARAMS,
    analyse=analyse_suppression,
)
def nonlinear_suppression(p: dict):
    offsets = p["offsets_arcsec"]
    yield Note(f"offset sweep over {len(offsets)} offsets, {offsets[0]:g} .. {offsets[-1]:g} arcsec")
    groups, readbacks = [], []
    for i, offset in enumerate(offsets):
        prefix = sweep_prefix(i)
        record = yield from set_and_record(prefix, analysis.SWEEP, offset)
        readbacks.append(record.values["offset_arcsec"])
        groups.append((yield from calibration(prefix, p, p["window_s"])))
        yield Checkpoint(f"offset {offset:g} arcsec done")
    fit = yield FitSweep("sweep-fit", tuple(readbacks), tuple(groups), tuple(p["positions_deg"]), tuple(p["freqs_hz"]))
    best = fit.values["best_offset_arcsec"]
    yield from set_and_record("B", analysis.AT_BEST, best)
    at_best = yield from calibration("B", p, p["verify_window_s"])
    corr = yield InertiaProductCorrection(
        "correction", at_best, best, p["angular_momentum_kgm2ps"], p["end_radius_mm"], p["removal_angle_deg"]
    )
    if not p["remove_mass"]:
        return
    mass_mg = round(corr.values["mass_mg"], 1)
    removal = {"mass_mg": mass_mg, "radius_mm": p["end_radius_mm"], "angle_deg": p["removal_angle_deg"]}
    yield RemoveMass(
        f"Dismount the PIGA, remove {mass_mg:g} mg from the float at each of 4 points (two per end, "
        f"{p['end_radius_mm']:g} mm from the axis, {p['removal_angle_deg']:g} deg from the pendulous mass) with the "
        "laser fine-weight adjusting machine, reassemble and remount it, then confirm.",
        ((MASS_REMOVAL, removal),),
        REMOUNT_S,
    )
    yield from set_and_record("A", analysis.AFTER_REMOVAL, best)
    yield from calibration("A", p, p["verify_window_s"])
