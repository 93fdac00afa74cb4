"""Seed 001: eight-point tumble calibration of a pendulous accelerometer in the gravity field, with temperature models.

`tumble`: at each temperature (the seed's normal, maximum and minimum; the default then
returns to normal, which separates the bias drift from the temperature coefficients) the chamber
is brought to it and soaked; then, in each of three cycles, the indexing head turns the
instrument through the nine test positions of Fig. 2 (0, 45, ..., 360 deg) on the forward stroke
and back on the back stroke, and at each one the voltmeter reads the output. The head starts
from -45 deg so that the first reading, too, is reached on a known hysteresis branch; the
chamber returns to the reference temperature at the end. Analysed by eq. 6 at each temperature
and eq. 4's temperature laws and hysteresis across them (procedures.tumble.analysis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.errors import DeviceTimeout
from drivers.voltmeter.protocol import MAX_SAMPLES, NPLC_LIMITS, OVERRANGE, RANGES_V, reading_s
from procedures.common.session_certificate import issue_certificate, result_provenance, session_uid
from procedures.tumble.analysis import READING, SOAK, STEP_DEG, analyse_tumble, position_deg, stroke_sequence
from procedures.tumble.certificate import certificate
from procedures.tumble.report import render_tumble_report, summary
from station.engine.params import Param
from station.engine.registry import Analysis, procedure
from station.engine.steps import Checkpoint, MoveIndex, Note, Step
from station.session import Measurement, Session
from station.twin.chamber_thermal import time_to_band_s

if TYPE_CHECKING:
    from station.engine.context import PlanContext, RunContext

CHAMBER = "temperature_chamber"
VOLTMETER = "voltmeter"
LAB_AMBIENT_C = 20.0  # planning assumes the chamber starts at the laboratory's temperature
SOAK_POLL_S = 10.0  # chamber status every 10 s of station time while it settles
SOAK_TIMEOUT_FACTOR = 2.0  # a chamber that needs twice the estimate (plus an hour) has a fault


def _check_chamber(ctx: PlanContext, setpoint_c: float, ramp_c_per_min: float) -> Any:
    """The chamber's section, once set point and ramp are within the station's limits."""
    sec = ctx.require(CHAMBER)
    if not sec.setpoint_min_c <= setpoint_c <= sec.setpoint_max_c:
        raise ctx.fail(
            "setpoint_c",
            setpoint_c,
            f"{sec.setpoint_min_c:g} .. {sec.setpoint_max_c:g} deg C ([{CHAMBER}] setpoint_min_c .. setpoint_max_c)",
        )
    if not 0 < ramp_c_per_min <= sec.ramp_max_c_per_min:
        raise ctx.fail(
            "ramp_c_per_min",
            ramp_c_per_min,
            f"0 < rate <= {sec.ramp_max_c_per_min:g} deg C/min ([{CHAMBER}] ramp_max_c_per_min)",
        )
    return sec


@dataclass(frozen=True)
class SoakChamber(Step):
    """Take the chamber to setpoint_c at ramp_c_per_min, wait until it is settled (set point reached, product within
    the stable band), then soak_s more (leaving the band restarts the soak). Result: Measurement "soak" with the
    temperature record (arrays t_s, temperature_c; seed 001 Fig. 4 b, d) and the time it took to settle."""

    name: str
    setpoint_c: float
    ramp_c_per_min: float
    soak_s: float

    @property
    def key(self) -> str:
        return self.name

    def _estimate_s(self, chamber: Any, start_c: float) -> float:
        """Settling (station.twin.chamber_thermal) plus the soak; `chamber`: its config section or its driver."""
        rate = self.ramp_c_per_min / 60.0
        return (
            time_to_band_s(start_c, self.setpoint_c, rate, chamber.time_constant_s, chamber.stable_band_c) + self.soak_s
        )

    def _values(self, settled_s: float) -> dict:
        return {
            "setpoint_c": self.setpoint_c,
            "ramp_c_per_min": self.ramp_c_per_min,
            "soak_s": self.soak_s,
            "settled_s": settled_s,
        }

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        sec = _check_chamber(ctx, self.setpoint_c, self.ramp_c_per_min)
        if not 0 <= self.soak_s <= 86400:
            raise ctx.fail("soak_s", self.soak_s, "0 .. 86400 s")
        start_c = ctx.state.devices.get(CHAMBER, LAB_AMBIENT_C)
        dt = self._estimate_s(sec, start_c)
        ctx.state.devices[CHAMBER] = self.setpoint_c
        arrays = {"t_s": ctx.state.t_s + np.array([0.0, dt]), "temperature_c": np.array([start_c, self.setpoint_c])}
        return dt, Measurement(self.key, SOAK, self._values(dt - self.soak_s), arrays)

    def run(self, ctx: RunContext) -> Measurement:
        chamber = ctx.hw.device(CHAMBER)
        chamber.check_alarms()
        start_c = chamber.temperature_c()
        chamber.set_ramp_rate(self.ramp_c_per_min)
        chamber.set_setpoint(self.setpoint_c)
        t0 = ctx.clock.now_s()
        limit_s = SOAK_TIMEOUT_FACTOR * self._estimate_s(chamber, start_c) + 3600.0
        t_s, temps = [], []
        since: float | None = None  # in the band since
        while True:
            chamber.check_alarms()
            st = chamber.status()
            now = ctx.clock.now_s()
            t_s.append(now)
            temps.append(st.temperature_c)
            if not chamber.settled(st):
                since = None
            elif since is None:
                since = now
            if since is not None and now - since >= self.soak_s:
                break
            if now - t0 > limit_s:
                raise DeviceTimeout(
                    "temperature chamber",
                    f"not settled within +-{chamber.stable_band_c:g} C of "
                    f"{self.setpoint_c:g} C after {now - t0:.0f} s (at {st.temperature_c:.2f} C)",
                )
            ctx.wait_s(SOAK_POLL_S)
        arrays = {"t_s": np.array(t_s), "temperature_c": np.array(temps)}
        return Measurement(self.key, SOAK, self._values(since - t0), arrays)


@dataclass(frozen=True)
class SetChamber(Step):
    """Command a set point and ramp and go on without waiting (the chamber's return to the reference at the end)."""

    setpoint_c: float
    ramp_c_per_min: float

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        _check_chamber(ctx, self.setpoint_c, self.ramp_c_per_min)
        ctx.state.devices[CHAMBER] = self.setpoint_c
        return 0.0, self.setpoint_c

    def run(self, ctx: RunContext) -> float:
        chamber = ctx.hw.device(CHAMBER)
        chamber.set_ramp_rate(self.ramp_c_per_min)
        chamber.set_setpoint(self.setpoint_c)
        return self.setpoint_c


@dataclass(frozen=True)
class TumbleReading(Step):
    """Turn the head to test position J, dwell, read the output with the voltmeter and the chamber's temperature.

    Result: Measurement "tumble" (values block, J, stroke, cycle, setpoint_c, position_deg, from_deg (where the
    head came from: the hysteresis branch), t_s (mid-reading, station time), volts (mean), volts_sd, temperature_c;
    array volts of every reading).
    """

    name: str
    block: int  # the temperature's place in the session
    J: int
    stroke: int
    cycle: int
    setpoint_c: float
    dwell_s: float
    range_v: float
    nplc: float
    samples: int
    scale_v_per_g: float  # nominal, for the range check: the output reaches K1 (1 g + bias)

    @property
    def key(self) -> str:
        return self.name

    def _values(self, from_deg: float, t_s: float, volts: np.ndarray, temperature_c: float) -> dict:
        return {
            "block": self.block,
            "J": self.J,
            "stroke": self.stroke,
            "cycle": self.cycle,
            "setpoint_c": self.setpoint_c,
            "position_deg": position_deg(self.J),
            "from_deg": from_deg,
            "t_s": t_s,
            "volts": float(np.mean(volts)),
            "volts_sd": float(np.std(volts, ddof=1)) if volts.size > 1 else 0.0,
            "samples": self.samples,
            "nplc": self.nplc,
            "range_v": self.range_v,
            "temperature_c": temperature_c,
        }

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        sec = ctx.require(VOLTMETER)
        ctx.require(CHAMBER)
        if self.J not in range(1, 10):
            raise ctx.fail("J", self.J, "a test position 1 .. 9")
        target = position_deg(self.J)
        ctx.check_position(target)
        if self.range_v not in RANGES_V:
            raise ctx.fail("range_v", self.range_v, ", ".join(f"{r:g}" for r in RANGES_V) + " V")
        peak_v = 1.1 * abs(self.scale_v_per_g)  # 1 g plus a bias of up to 0.1 g
        if peak_v > OVERRANGE * self.range_v:
            raise ctx.fail(
                "range_v", self.range_v, f"a range that holds {peak_v:.3g} V (1.1 g at {self.scale_v_per_g:g} V/g)"
            )
        if not NPLC_LIMITS[0] <= self.nplc <= NPLC_LIMITS[1]:
            raise ctx.fail("nplc", self.nplc, f"{NPLC_LIMITS[0]:g} .. {NPLC_LIMITS[1]:g} power-line cycles")
        if not 1 <= self.samples <= MAX_SAMPLES:
            raise ctx.fail("samples", self.samples, f"1 .. {MAX_SAMPLES}")
        if not 0 <= self.dwell_s <= 600:
            raise ctx.fail("dwell_s", self.dwell_s, "0 .. 600 s")
        from_deg = ctx.state.position_deg
        dt = ctx.move_head(target) + self.dwell_s + reading_s(self.nplc, self.samples, sec.line_hz)
        volts = np.full(self.samples, self.scale_v_per_g * math.cos(math.radians(target)))
        temperature = ctx.state.devices.get(CHAMBER, LAB_AMBIENT_C)
        values = self._values(from_deg, ctx.state.t_s + dt, volts, temperature)
        return dt, Measurement(self.key, READING, values, {"volts": volts})

    def run(self, ctx: RunContext) -> Measurement:
        from_deg = ctx.position_deg
        ctx.move_head(position_deg(self.J))
        ctx.wait_s(self.dwell_s)
        reading = ctx.hw.device(VOLTMETER).measure(self.range_v, self.nplc, self.samples)
        chamber = ctx.hw.device(CHAMBER)
        chamber.check_alarms()
        temperature = chamber.temperature_c()
        t_s = 0.5 * (reading.start_s + reading.end_s)
        values = self._values(
            from_deg if from_deg is not None else position_deg(self.J), t_s, reading.volts, temperature
        )
        return Measurement(self.key, READING, values, {"volts": reading.volts})


PARAMS = (
    Param("temperatures_c", list, default=[20.0, 80.0, -40.0, 20.0], min=-100.0, max=200.0, unit="deg C",
          help="test temperatures in order: seed 001's normal, maximum and minimum, and back to normal, which "
               "separates the bias drift from its temperature coefficients"),
    Param("reference_c", float, default=20.0, min=-100.0, max=200.0, unit="deg C",
          help="T0 of eq. 4: the temperature of the certified values"),
    Param("cycles", int, default=3, min=1, max=10, help="forward and back strokes per temperature (seed 001: 3)"),
    Param("ramp_c_per_min", float, default=1.0, min=0.01, max=20.0, unit="deg C/min", help="chamber ramp rate"),
    Param("soak_s", float, default=1800.0, min=0.0, max=86_400.0, unit="s",
          help="soak once the product temperature is within the chamber's stable band"),
    Param("dwell_s", float, default=10.0, min=0.0, max=600.0, unit="s", help="settling at each position"),
    Param("range_v", float, default=2.0, min=0.2, max=1000.0, unit="V", help="voltmeter range"),
    Param("nplc", float, default=10.0, min=0.01, max=50.0, unit="PLC", help="voltmeter aperture"),
    Param("samples", int, default=10, min=1, max=MAX_SAMPLES, help="readings averaged at each position"),
    Param("scale_v_per_g", float, default=1.35, min=0.001, max=100.0, unit="V/g",
          help="nominal output per g, for the range check (AL-15: 1.2 .. 1.5 mA/g across 1 kOhm)"),
)  # fmt: skip


def analyse(session: Session) -> Analysis:
    """Eq. 6 at each temperature, eq. 4's temperature laws and hysteresis across them, the report and the
    certificate."""
    reference_c = float(session.meta.get("params", {}).get("reference_c", 20.0))
    r, points, model = analyse_tumble(session, reference_c)
    uid = session_uid(session)
    html = render_tumble_report(session, r, points, model, title=f"Session {uid}: eight-point tumble (seed 001)")
    results = {"eight_point": {"temperatures": [p.to_json() for p in points], "provenance": result_provenance(session)},
               "temperature_model": model.to_json()}  # fmt: skip
    files, why_not = issue_certificate(lambda: certificate(session, r, points, model), uid)
    return Analysis(results, html, "\n".join(filter(None, [summary(points, model), why_not])), files)


@procedure(
    "tumble",
    "Eight-point tumble of a pendulous accelerometer at several temperatures (seed 001)",
    PARAMS,
    analyse=analyse,
)
def tumble(p: dict):
    sequence = stroke_sequence(p["cycles"])
    yield Note(f"{len(p['temperatures_c'])} temperatures x {p['cycles']} cycles x 18 readings")
    yield MoveIndex(-STEP_DEG)  # the first reading at 0 deg is then on the rising branch, like every later one
    for block, setpoint in enumerate(p["temperatures_c"]):
        yield SoakChamber(f"soak-T{block + 1}", setpoint, p["ramp_c_per_min"], p["soak_s"])
        yield Checkpoint(f"at {setpoint:g} C")
        for cycle, stroke, J in sequence:
            yield TumbleReading(f"T{block + 1}-k{stroke}-J{J}", block, J, stroke, cycle, setpoint, p["dwell_s"],
                                p["range_v"], p["nplc"], p["samples"], p["scale_v_per_g"])  # fmt: skip
            if J == 1 and stroke % 2 == 0:
                yield Checkpoint(f"{setpoint:g} C, cycle {cycle} done")
    yield SetChamber(p["reference_c"], p["ramp_c_per_min"])
