"""Seed 003: PIGA calibration in the gravity field on the indexing head, with two PIGAs on one fixture.

- `multiposition.planning`: the position sequence before anything moves: uncertainty factors
  d_ii (Fig. 4), ES(n) (Fig. 5), the test time per position and in total versus n for
  equal-angle and equal-acceleration sequences (Figs. 6-7). Nothing moves.
- `multiposition`: the optimised process of seed 003 5.3. Setup 1 (A in pose 1, B
  in pose 2): self-alignment of A with its input axis horizontal (eqs. 52-56, repeated
  until within tolerance; the head's zero follows), the four-pose sequence counting both
  PIGAs at each position, then A's calibration sequences. The operator re-installs the
  PIGAs (A in pose 4, B in pose 3), self-alignment again, the four-pose sequence of setup
  2. Analysis: the head's angle-error harmonics from both setups (the orthogonal 4-pose
  method), then A's coefficients without and with them compensated.

Every window counts a preset precession angle (seed 003: 10 pi, 5 revolutions), so its
length is that angle over the rate: positions where an instrument's input axis is near
horizontal cost hours, and the dry run says so.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.errors import DriverError
from procedures.common.session_certificate import issue_certificate, result_provenance, session_uid
from procedures.integral_precession.alignment import Alignment
from procedures.multiposition import gravity_field as gf
from procedures.multiposition.alignment import ALIGNMENT_ANGLES_DEG, horizontal_axis_alignment
from procedures.multiposition.certificate import certificate
from procedures.multiposition.report import design_report, gravity_field_report
from procedures.multiposition.sequences import SCHEMES, on_head_grid_deg, sequence_deg
from procedures.multiposition.static_model import MODELS
from station.engine.params import Param
from station.engine.registry import Analysis, procedure
from station.engine.steps import Checkpoint, MeasurePoint, Note, OperatorAction, Recorded, Step
from station.session import Measurement, PointRecord, Session, StationInfo
from station.twin.fixture import POSES_DEG, SETUPS
from station.twin.plan import PULSES_PER_REV, preset_pulses

if TYPE_CHECKING:
    from station.engine.context import PlanContext, RunContext

SECOND_INSTRUMENT = "second_instrument"  # the device (drivers/second_instrument/driver.py)
SEED003_PRECESSION_REV = 5.0  # 10 pi rad per position (seed 003 5.2)


# ---- steps ---------------------------------------------------------------------------------------------


def _tags(dut: str, setup: int, pose: int, block: str) -> dict[str, str]:
    """A window's extra columns (piga-session/1 allows dut and pose; setup and block say what it was for)."""
    return {"dut": dut, "setup": str(setup), "pose": str(pose), "block": block}


@dataclass(frozen=True)
class PosedPoint(MeasurePoint):
    """A static window of PIGA A, tagged with the fixture setup, A's pose and the block it belongs to."""

    setup: int = 1
    pose: int = 1
    block: str = ""

    def _tagged(self, record: PointRecord) -> PointRecord:
        return replace(record, extra={**record.extra, **_tags("A", self.setup, self.pose, self.block)})

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        dt, record = super().plan(ctx)
        # The window's length follows the instrument's angle, not the head's.
        tm_s = ctx.model.window_s(self.position_deg + POSES_DEG[self.pose], self.preset_pulses)
        return dt - record.Tm_s + tm_s, self._tagged(replace(record, Tm_s=tm_s))

    def run(self, ctx: RunContext) -> Recorded:
        out = super().run(ctx)
        return Recorded(self._tagged(out.record), out.raw)


@dataclass(frozen=True)
class SecondInstrumentWindow(Step):
    """A static window of PIGA B at the head's position, counted on the second counter/timer channel.

    Result: a PointRecord of B (extra dut = B), stored with A's points.
    """

    name: str
    position_deg: float
    preset_pulses: int
    setup: int
    pose: int
    block: str
    settle_s: float = 5.0

    @property
    def key(self) -> str:
        return self.name

    def _record(self, sequence: int, start_s: float, pulses: int, tm_s: float) -> PointRecord:
        return PointRecord(self.key, sequence, start_s, self.position_deg, 0.0, "static", pulses, tm_s,
                           extra=_tags("B", self.setup, self.pose, self.block))  # fmt: skip

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        ctx.require(SECOND_INSTRUMENT)
        ctx.check_position(self.position_deg)
        if not (isinstance(self.preset_pulses, int) and 0 < self.preset_pulses <= ctx.model.max_preset):
            raise ctx.fail("preset_pulses", self.preset_pulses, f"a whole number 1 .. {ctx.model.max_preset}")
        if self.pose not in POSES_DEG:
            raise ctx.fail("pose", self.pose, "a fixture pose 1, 2, 3 or 4")
        dt = ctx.move_head(self.position_deg) + ctx.set_table(0.0) + self.settle_s
        tm_s = ctx.model.window_s(self.position_deg + POSES_DEG[self.pose], self.preset_pulses)
        record = self._record(ctx.state.sequence, ctx.state.t_s + dt, self.preset_pulses, tm_s)
        ctx.state.sequence += 1
        return dt + tm_s, record

    def run(self, ctx: RunContext) -> Recorded:
        ctx.move_head(self.position_deg)
        ctx.set_table(0.0, self.settle_s)
        ctx.check_abort()
        board = ctx.hw.device(SECOND_INSTRUMENT)
        try:
            result = board.measure(self.preset_pulses, on_event=ctx.window_monitor(self.key, self.preset_pulses))
        except DriverError as exc:
            # The board is the station's counter/timer model: say which of the two channels failed.
            raise type(exc)(f"second instrument's counter/timer on {board.port}",
                            str(exc).removeprefix(f"{exc.device}: ")) from exc  # fmt: skip
        except BaseException:  # an abort or stop: leave the second board idle too
            with contextlib.suppress(DriverError):
                board.abort()
            raise
        return Recorded(self._record(ctx.sequence, result.open_s - ctx.t0_s, result.pulses, result.Tm_s))


@dataclass(frozen=True)
class SelfAlignment(Step):
    """PIGA A's misalignment from its two horizontal-axis windows (eqs. 55-56), and the head zero from now on."""

    name: str
    setup: int
    round: int
    rate_90_radps: float
    rate_270_radps: float
    zero_before_deg: float
    kz_radps_per_g: float
    sigma_rate_radps: float
    sigma_latitude_deg: float
    sigma_kz: float

    @property
    def key(self) -> str:
        return self.name

    def _measurement(self, station: StationInfo, nominal: bool = False) -> Measurement:
        a: Alignment = horizontal_axis_alignment(
            self.rate_90_radps, self.rate_270_radps, station, kz_radps_per_g=self.kz_radps_per_g,
            sigma_rate_radps=self.sigma_rate_radps, sigma_latitude_rad=math.radians(self.sigma_latitude_deg),
            sigma_kz=self.sigma_kz,
        )  # fmt: skip
        theta0 = 0.0 if nominal else a.dtheta_h_rad
        values = {"setup": self.setup, "round": self.round, "misalignment_rad": theta0, "sigma_rad": a.sigma_rad,
                  "k0+ky_radps": a.k0_radps, "zero_before_deg": self.zero_before_deg,
                  "zero_deg": self.zero_before_deg + math.degrees(theta0)}  # fmt: skip
        return Measurement(self.key, gf.ALIGNMENT, values)

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        # The nominal station is aligned (its nominal rates have no earth rate for eq. 55 to remove).
        return 0.0, self._measurement(ctx.model.station, nominal=True)

    def run(self, ctx: RunContext) -> Measurement:
        m = self._measurement(ctx.hw.station)
        v = m.values
        ctx.event("alignment", f"setup {self.setup} round {self.round}: misalignment {v['misalignment_rad']:.3e} "
                               f"± {v['sigma_rad']:.1e} rad; head zero {v['zero_deg']:.6f} deg")  # fmt: skip
        return m


# ---- parameters ----------------------------------------------------------------------------------------


def _scheme(name: str, default: str, help_: str) -> Param:
    return Param(name, str, default=default, choices=SCHEMES, help=help_)


def _count(name: str, help_: str) -> Param:
    return Param(name, int, default=22, min=6, max=72, help=help_)


MODEL = Param("model", str, default="seed003", choices=tuple(MODELS),
              help="static model: seed003 = k0+ky, kz, kzz-ky, koq (eq. 14); physics = that and k3")  # fmt: skip
PRECESSION = Param("precession_rev", float, default=SEED003_PRECESSION_REV, min=1 / 64, max=100.0, unit="rev",
                   help="preset precession per window, in revolutions (seed 003: 10 pi rad = 5)")  # fmt: skip
GRAVITY_FIELD_PARAMS = (
    MODEL,
    Param("harmonics", int, default=3, min=1, max=4, help="orders of the head's angle error identified (seed: 3)"),
    _scheme("setup1_scheme", "equal_acceleration", "four-pose sequence of setup 1 (A pose 1, B pose 2)"),
    _count("setup1_n", "positions of the setup-1 four-pose sequence"),
    _scheme("setup2_scheme", "equal_angle", "four-pose sequence of setup 2 (A pose 4, B pose 3)"),
    _count("setup2_n", "positions of the setup-2 four-pose sequence"),
    Param("calibration_schemes", str, default="both", choices=("both", *SCHEMES, "none"),
          help="A's calibration sequences in setup 1"),
    _count("calibration_n", "positions of each calibration sequence"),
    PRECESSION,
    Param("alignment_rev", float, default=1.0, min=1 / 64, max=100.0, unit="rev",
          help="preset precession of a self-alignment window (its rate is about k0: hours per revolution)"),
    Param("max_window_s", float, default=0.0, min=0.0, max=1e7, unit="s",
          help="0: every window counts its preset; else fewer whole revolutions (at least one) where it would "
               "take longer"),
    Param("alignment_tolerance_arcsec", float, default=30.0, min=0.1, max=600.0, unit="arcsec",
          help="self-alignment repeats until the misalignment is within this (seed 003: 30)"),
    Param("alignment_rounds", int, default=3, min=1, max=5, help="self-alignment rounds at most"),
    Param("kz_radps_per_g", float, default=0.55, min=0.01, max=10.0, unit="rad/s/g",
          help="initial scale factor for eq. 55"),
    Param("sigma_rate_radps", float, default=6.8e-6, min=0.0, max=1e-3, unit="rad/s",
          help="output uncertainty for eq. 56 (seed 003: 6.8e-6)"),
    Param("sigma_latitude_deg", float, default=0.1, min=0.0, max=10.0, unit="deg", help="latitude uncertainty"),
    Param("sigma_kz", float, default=1e-4, min=0.0, max=1.0, unit="rad/s/g", help="uncertainty of the initial kz"),
    Param("settle_s", float, default=5.0, min=0.0, max=600.0, unit="s", help="settling after each head move"),
    Param("reinstall_s", float, default=1800.0, min=0.0, max=86400.0, unit="s",
          help="expected time for the operator to re-install the PIGAs"),
)  # fmt: skip


def _preset(p: dict, rev: float, instrument_deg: float) -> int:
    """The preset of a window: `rev` revolutions, or with max_window_s the whole revolutions (at least one)
    that fit in it at the planning estimate of the rate (station.twin.plan.preset_pulses)."""
    preset = max(1, round(rev * PULSES_PER_REV))
    if p["max_window_s"] > 0:
        preset = min(preset, preset_pulses(instrument_deg, p["max_window_s"], p["kz_radps_per_g"]))
    return preset


# ---- the session ---------------------------------------------------------------------------------------


def _self_alignment(p: dict, setup: int, pose_a: int):
    """Align A's input axis with the head's zero (eqs. 52-56); returns the head zero in deg."""
    zero_deg = 0.0
    tolerance_rad = math.radians(p["alignment_tolerance_arcsec"] / 3600)
    for rnd in range(1, p["alignment_rounds"] + 1):
        rates = []
        for psi in ALIGNMENT_ANGLES_DEG:
            head = on_head_grid_deg(psi - POSES_DEG[pose_a] - zero_deg)
            record = yield PosedPoint(f"S{setup}-AL{rnd}-{psi:g}", head, 0.0, _preset(p, p["alignment_rev"], psi),
                                      p["settle_s"], setup=setup, pose=pose_a, block="alignment")  # fmt: skip
            rates.append(record.measured_rate_radps(PULSES_PER_REV))
        result = yield SelfAlignment(f"S{setup}-AL{rnd}", setup, rnd, rates[0], rates[1], zero_deg,
                                     p["kz_radps_per_g"], p["sigma_rate_radps"], p["sigma_latitude_deg"],
                                     p["sigma_kz"])  # fmt: skip
        zero_deg = result.values["zero_deg"]
        if abs(result.values["misalignment_rad"]) <= tolerance_rad:
            return zero_deg
    yield Note(f"setup {setup}: misalignment still beyond {p['alignment_tolerance_arcsec']:g} arcsec after "
               f"{p['alignment_rounds']} rounds; the head zero keeps the last estimate")  # fmt: skip
    return zero_deg


def _four_pose_sequence(p: dict, setup: int, zero_deg: float):
    pose_a, pose_b = SETUPS[setup]
    rev = p["precession_rev"]
    positions = sequence_deg(p[f"setup{setup}_scheme"], p[f"setup{setup}_n"])  # A's instrument angles
    for i, psi in enumerate(positions):
        head = on_head_grid_deg(psi - POSES_DEG[pose_a] - zero_deg)
        psi_b = head + POSES_DEG[pose_b] + zero_deg
        yield PosedPoint(f"S{setup}-{i + 1:02d}-{head:g}deg-A", head, 0.0, _preset(p, rev, psi), p["settle_s"],
                         setup=setup, pose=pose_a, block="four_pose")  # fmt: skip
        yield SecondInstrumentWindow(f"S{setup}-{i + 1:02d}-{head:g}deg-B", head, _preset(p, rev, psi_b), setup,
                                     pose_b, "four_pose", p["settle_s"])  # fmt: skip
        yield Checkpoint(f"setup {setup}, position {i + 1} of {len(positions)}")


def _calibration_sequences(p: dict, zero_deg: float):
    schemes = {"both": SCHEMES, "none": ()}.get(p["calibration_schemes"], (p["calibration_schemes"],))
    for scheme in schemes:
        for i, psi in enumerate(sequence_deg(scheme, p["calibration_n"])):
            head = on_head_grid_deg(psi - zero_deg)
            yield PosedPoint(f"C-{scheme}-{i + 1:02d}-{head:g}deg", head, 0.0, _preset(p, p["precession_rev"], psi),
                             p["settle_s"], setup=1, pose=1, block=gf.CALIBRATION + scheme)  # fmt: skip
        yield Checkpoint(f"calibration sequence {scheme} done")


def analyse_gravity_field(session: Session) -> Analysis:
    """Harmonics by the 4-pose method, then A's coefficients without and with them; the report and the
    certificate."""
    p = session.meta.get("params", {})
    res = gf.analyse_gravity_field(session, MODELS[p.get("model", "seed003")], int(p.get("harmonics", 3)))
    uid = session_uid(session)
    html = gravity_field_report(res, f"Session {uid}: gravity field on the indexing head (seed 003)", p)
    if res.four_pose is not None:
        fp = res.four_pose
        h = ", ".join(f"{v:.2e}±{s:.0e}" for v, s in zip(fp.harmonics_rad, fp.harmonic_sigmas_rad, strict=True))
        lines = [f"angle-error harmonics (rad): {h}"]
    else:
        lines = [res.four_pose_error]
    for cal in res.calibrations:
        for name, fit in (("uncompensated", cal.uncompensated), ("compensated", cal.compensated)):
            if fit is not None:
                coefs = ", ".join(f"{n} = {v:.6e} ± {s:.1e}" for n, v, s in zip(fit.names, fit.values, fit.sigmas,
                                                                                  strict=True))  # fmt: skip
                lines.append(f"{cal.scheme} {name}: {coefs}; sigma = {fit.sigma_residual:.2e} rad/s")
    files, why_not = issue_certificate(lambda: certificate(session, res), uid)
    if not files:
        lines.append(why_not or "no certificate: the session has no calibration sequence of A")
    results = {"gravity_field": res.to_json() | {"provenance": result_provenance(session)}}
    return Analysis(results, html, "\n".join(lines), files)


@procedure(
    "multiposition",
    "Gravity-field calibration on the indexing head with two PIGAs: self-alignment, orthogonal 4-pose "
    "angle-error harmonics, calibration with them compensated (seed 003)",
    GRAVITY_FIELD_PARAMS,
    analyse=analyse_gravity_field,
)
def gravity_field(p: dict):
    yield Note(f"setup 1: PIGA A in pose 1, B in pose 2; {p['precession_rev']:g} revolutions per window")
    zero_deg = yield from _self_alignment(p, 1, SETUPS[1][0])
    yield from _four_pose_sequence(p, 1, zero_deg)
    yield from _calibration_sequences(p, zero_deg)
    yield OperatorAction("Re-install the PIGAs: A in pose 4, B in pose 3 (seed 003 Fig. 3), then confirm",
                         (("fixture_poses", list(SETUPS[2])),), p["reinstall_s"])  # fmt: skip
    zero_deg = yield from _self_alignment(p, 2, SETUPS[2][0])
    yield from _four_pose_sequence(p, 2, zero_deg)


# ---- planning ------------------------------------------------------------------------------------------


def analyse_planning(session: Session) -> Analysis:
    """d_ii, ES(n) and test time of both sequences (seed 003 5.1-5.2)."""
    p = session.meta.get("params", {})
    ns = np.arange(p["n_min"], p["n_max"] + 1)
    html, results = design_report(MODELS[p["model"]], ns, p["n"], 2 * math.pi * p["precession_rev"], p["k0_radps"],
                                  p["kz_radps_per_g"], session.station)  # fmt: skip
    totals = {s: results[s]["total_test_time_s"][list(ns).index(p["n"])] / 60 for s in SCHEMES if p["n"] in ns}
    summary = f"{p['n']} positions, total window time: " + ", ".join(f"{s} {t:.0f} min" for s, t in totals.items())
    return Analysis({"planning": results}, html, summary)


@procedure(
    "multiposition.planning",
    "Position sequence design on the indexing head: d_ii, ES(n), test time per position and in total (seed 003 "
    "5.1-5.2); nothing moves",
    (
        MODEL,
        Param("n", int, default=22, min=6, max=200, help="positions of the design to detail"),
        Param("n_min", int, default=6, min=4, max=200, help="smallest n of the curves"),
        Param("n_max", int, default=60, min=5, max=200, help="largest n of the curves"),
        PRECESSION,
        Param("k0_radps", float, default=4e-4, min=-1e-2, max=1e-2, unit="rad/s", help="bias for the rate estimate"),
        Param(
            "kz_radps_per_g",
            float,
            default=0.55,
            min=0.01,
            max=10.0,
            unit="rad/s/g",
            help="scale factor for the rate estimate",
        ),
    ),
    analyse=analyse_planning,
)
def planning(p: dict):
    yield Note(f"planning position sequences of {p['n_min']}..{p['n_max']} positions; nothing moves")
