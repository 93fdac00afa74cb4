"""Seed 000's error-source experiments (6.1.1-6.1.3), each a procedure of its own with its report.

- `integral_precession.parasitic_translation`: the grating record at each frequency, its harmonics
  relative to the crank phase (eq. 30, Table 5), the sampling-delay error (eq. 31) and
  the fit Zs1(w) = z0 + z1 w (eq. 32).
- `integral_precession.frequency_stability`: consecutive periods timed at each frequency (Table 6,
  eq. 33), judged against Table 4's stability < 5e-4.
- `integral_precession.parasitic_rotation`: an electronic gradiometer on the table top read at the
  crank phases 2 pi i / N over whole turns (eq. 34, Table 7).

The results' "compensation" blocks hold what the integral identification compensates
(seed 000 6.1: "the error calibration model should be compensated") with the uncertainty it is budgeted at,
named exactly as the parameters of integral_precession that take them (USAGE): zs1_z0_m (m), zs1_z1_m_s
(m s/rad) of Zs1(w) = z0 + z1 w with their sigmas and correlation, axs1_rad (rad) and its sigma, eps_f and
its sigma; that procedure builds procedures.integral_precession.identify.Compensation from the values, and its
budget takes a table error these give as measured, at their sigma (issue 32: an error not measured is
budgeted at seed 000's size).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.errors import DriverError
from procedures.common.session_certificate import session_uid
from procedures.integral_precession.error_source_report import rotation_report, stability_report, translation_report
from procedures.integral_precession.frequency_stability import mean_eps_f, table6_row
from procedures.integral_precession.parasitic_rotation import AXES, eq34, fit_rotation, slot_means
from procedures.integral_precession.table_motion import crank_phase, fit_zs1, sampling_delay_error_m, waveform
from station import constants
from station.engine.params import Param
from station.engine.registry import Analysis, procedure
from station.engine.steps import CaptureGrating, MeasureFrequency, Note, SetVibration, Step
from station.records import Field, declare
from station.session import Measurement, Session
from station.twin.table_tilt import ARCSEC_RAD

if TYPE_CHECKING:
    from station.engine.context import PlanContext, RunContext

TABLE5_FREQS_HZ = [1.0, 3.0, 5.0, 7.0, 9.0, 10.0]
TABLE6_FREQS_HZ = [0.1, *map(float, range(1, 11))]
INTEGRAL = "integral_precession"  # the procedure whose identification the results compensate
USAGE = f"the compensation block's keys are [params] of {INTEGRAL}, to be copied as they are"

TRANSLATION_PARAMS = (
    Param("freqs_hz", list, default=TABLE5_FREQS_HZ, min=0.1, max=10.0, unit="Hz",
          help="vibration frequencies (seed 000 Table 5)"),
    Param("periods", int, default=5, min=2, max=1000, help="crank turns of grating record at each frequency"),
    Param("harmonics", int, default=3, min=2, max=10, help="harmonics fitted, j = 1..n (eq. 30)"),
    Param("settle_s", float, default=5.0, min=0.0, max=600.0, unit="s", help="settling after each change"),
)  # fmt: skip

STABILITY_PARAMS = (
    Param("freqs_hz", list, default=TABLE6_FREQS_HZ, min=0.1, max=10.0, unit="Hz",
          help="vibration frequencies (seed 000 Table 6)"),
    Param("periods", int, default=10, min=2, max=10_000, help="consecutive periods timed at each frequency (seed: 10)"),
    Param("settle_s", float, default=5.0, min=0.0, max=600.0, unit="s", help="settling after each change"),
    Param("stability_max", float, default=constants.FREQ_STABILITY_MAX, min=0.0, max=1.0,
          help="specification of sigma_f / f (seed 000 Table 4)"),
    Param("kz_radps_per_g", float, default=constants.KZ_RADPS_PER_G, min=0.0, max=100.0, unit="rad/s/g",
          help="the instrument's kz, for eq. 33's rate error"),
)  # fmt: skip

ROTATION_PARAMS = (
    Param("freq_hz", float, default=0.1, min=0.1, max=1.0, unit="Hz",
          help="crank frequency: a slow turn, so that the gradiometer reads the quasi-static tilt"),
    Param("turns", int, default=2, min=1, max=100, help="whole crank turns of readings"),
    Param("readings_per_turn", int, default=12, min=4, max=120,
          help="readings at the crank phases 2 pi i / N (eq. 34: N = 12)"),
    Param("settle_s", float, default=5.0, min=0.0, max=600.0, unit="s", help="settling after the crank is at speed"),
)  # fmt: skip


def _params(session: Session, declared: tuple[Param, ...]) -> dict[str, Any]:
    """The session's parameters, declared defaults for any it does not carry (an imported session)."""
    given = session.meta.get("params") or {}
    return {p.name: given.get(p.name, p.default) for p in declared}


def _of_kind(session: Session, kind: str) -> list[Measurement]:
    found = [m for m in session.measurements if m.kind == kind]
    if not found:
        raise ValueError(f"the session holds no {kind!r} measurement to analyse")
    return found


# ---------------------------------------------------------------- parasitic translation


def analyse_translation(session: Session) -> Analysis:
    """Table 5 (eqs. 30-31) and the fit of eq. 32 from every grating record of the session."""
    p = _params(session, TRANSLATION_PARAMS)
    a0 = session.station.A0_m
    motions = _of_kind(session, "motion")
    waves = [
        waveform(m.arrays["t_s"], m.arrays["z_m"], m.arrays["reference_t_s"], a0, 1.0 / m.values["freq_hz"],
                 p["harmonics"])
        for m in motions
    ]  # fmt: skip
    line = fit_zs1([w.w_radps for w in waves], [w.zs_m[0] for w in waves], [w.sigma_zs_m[0] for w in waves])
    rows = []
    for m, w in zip(motions, waves, strict=True):
        row = {"key": m.key, "commanded_hz": m.values["freq_hz"], "freq_hz": w.freq_hz,
               "sigma_freq_hz": w.sigma_freq_hz, "A_s_m": w.mean_m, "sigma_A_s_m": w.sigma_mean_m,
               "dA_max_m": float(sampling_delay_error_m(w.freq_hz, a0)), "residual_rms_m": w.residual_rms_m,
               "n_samples": w.n_samples, "n_crossings": w.n_crossings}  # fmt: skip
        for j in range(len(w.zs_m)):
            row |= {f"Zs{j + 1}_m": float(w.zs_m[j]), f"sigma_Zs{j + 1}_m": float(w.sigma_zs_m[j]),
                    f"Zc{j + 1}_m": float(w.zc_m[j]), f"sigma_Zc{j + 1}_m": float(w.sigma_zc_m[j])}  # fmt: skip
        rows.append(row)
    fit = {"z0_m": line.z0_m, "sigma_z0_m": line.sigma_z0_m, "z1_m_s_per_rad": line.z1_m_s_per_rad,
           "sigma_z1_m_s_per_rad": line.sigma_z1_m_s_per_rad, "cov": line.cov.tolist(), "chi2": line.chi2,
           "dof": line.dof}  # fmt: skip
    comp = {
        "zs1_z0_m": line.z0_m, "zs1_z1_m_s": line.z1_m_s_per_rad,
        "zs1_z0_sigma_m": line.sigma_z0_m, "zs1_z1_sigma_m_s": line.sigma_z1_m_s_per_rad,
        "zs1_z0_z1_corr": float(np.clip(line.cov[0, 1] / np.sqrt(line.cov[0, 0] * line.cov[1, 1]), -1.0, 1.0)),
    }  # fmt: skip
    result = {"table5": rows, "zs1_fit": fit, "compensation": comp, "compensation_usage": USAGE,
              "units": "m, Hz, rad/s"}  # fmt: skip
    uid = session_uid(session)
    html = translation_report(
        f"Session {uid}: parasitic translation (seed 000 6.1.1)",
        [m.values["freq_hz"] for m in motions],
        waves,
        line,
        a0,
    )
    summary = (f"Zs1(w) = z0 + z1 w: z0 = {line.z0_m:.4e} ± {line.sigma_z0_m:.1e} m, "
               f"z1 = {line.z1_m_s_per_rad:.4e} ± {line.sigma_z1_m_s_per_rad:.1e} m s/rad "
               f"(chi2 {line.chi2:.2f} for {line.dof} dof) from {len(waves)} frequencies")  # fmt: skip
    return Analysis({"parasitic_translation": result}, html, summary)


@procedure("integral_precession.parasitic_translation",
           "Parasitic translation of the vibration table (seed 000 Table 5)", TRANSLATION_PARAMS,
           analyse=analyse_translation)  # fmt: skip
def parasitic_translation(p: dict):
    yield Note(f"grating records of {p['periods']} turns at {p['freqs_hz']} Hz")
    for f in p["freqs_hz"]:
        yield SetVibration(f, p["settle_s"])
        yield CaptureGrating(f"motion-{f:g}Hz", (p["periods"] + 1) / f)


# ---------------------------------------------------------------- frequency stability


def analyse_stability(session: Session) -> Analysis:
    """Table 6 and eq. 33 from every frequency measurement of the session, against Table 4's specification."""
    p = _params(session, STABILITY_PARAMS)
    st = session.station
    rows = [
        table6_row(m.values["commanded_hz"], m.values["freq_hz"], m.values["stability"], m.values["periods"],
                   a0_m=st.A0_m, kz_radps_per_g=p["kz_radps_per_g"], g_mps2=st.g_mps2)
        for m in _of_kind(session, "frequency")
    ]  # fmt: skip
    eps, sigma_eps, chi2_dof = mean_eps_f(rows)
    passed = all(r.passes(p["stability_max"]) for r in rows)
    table = [
        {"commanded_hz": r.commanded_hz, "fbar_hz": r.fbar_hz, "sigma_fbar_hz": r.sigma_fbar_hz,
         "delta_f_hz": r.delta_f_hz, "stability": r.stability, "eps_f": r.eps_f, "periods": r.periods,
         "delta_alpha_radps": r.delta_alpha_radps, "pass": r.passes(p["stability_max"])}
        for r in rows
    ]  # fmt: skip
    result = {
        "table6": table, "stability_max": p["stability_max"], "passed": passed,
        "eps_f": {"value": eps, "sigma": sigma_eps, "chi2_per_dof": chi2_dof},
        "compensation": {"eps_f": eps, "eps_f_sigma": sigma_eps}, "compensation_usage": USAGE,
        "notes": "delta_f_hz = commanded - fbar (seed 000 6.1.2); eps_f = fbar / f - 1 (the twin's frequency_error)",
    }  # fmt: skip
    uid = session_uid(session)
    html = stability_report(f"Session {uid}: frequency stability (seed 000 6.1.2)", rows, p["stability_max"], eps,
                            sigma_eps)  # fmt: skip
    worst = max(rows, key=lambda r: r.stability)
    summary = (f"{'PASS' if passed else 'FAIL'}: sigma_f/f at most {worst.stability:.2e} ({worst.commanded_hz:g} Hz) "
               f"against {p['stability_max']:.1e}; max |Delta f| {max(abs(r.delta_f_hz) for r in rows):.2e} Hz; "
               f"eps_f = {eps:.3e} ± {sigma_eps:.1e}")  # fmt: skip
    return Analysis({"frequency_stability": result}, html, summary)


@procedure("integral_precession.frequency_stability", "Vibration frequency stability (seed 000 Table 6)",
           STABILITY_PARAMS, analyse=analyse_stability)  # fmt: skip
def frequency_stability(p: dict):
    yield Note(f"{p['periods']} periods timed at {p['freqs_hz']} Hz")
    for f in p["freqs_hz"]:
        yield SetVibration(f, p["settle_s"])
        yield MeasureFrequency(f"frequency-{f:g}Hz", p["periods"])


# ---------------------------------------------------------------- parasitic rotation

# Crossings recorded before and after the readings fix the crank phase between them:
# a little over one turn of grating record holds at least one crossing.
CROSSING_CAPTURE_TURNS = 1.05


TILT = declare(
    "tilt",
    [Field("freq_hz", "float64", "Hz", lo=0.0, hi=100.0, doc="commanded crank frequency"),
     Field("turns", "int64", "", lo=1), Field("readings_per_turn", "int64", "", lo=1),
     Field("position_deg", "float64", "deg", nullable=True, doc="indexing head angle (null before any move)")],
    arrays=[Field("t_s", "float64", "s", doc="reading times, station time"),
            Field("phi_x_arcsec", "float64", "arcsec"), Field("phi_y_arcsec", "float64", "arcsec"),
            Field("phi_z_arcsec", "float64", "arcsec"),
            Field("reference_t_s", "float64", "s", doc="reference-mark crossings around the readings")],
    doc="tilts of the table top through whole crank turns (seed 000 Table 7, eq. 34)",
)  # fmt: skip


@dataclass(frozen=True)
class RecordTilt(Step):
    """Gradiometer readings at the crank phases 2 pi i / N over whole turns, with the crossings that fix psi (eq. 34).

    The crank must be turning. One turn of reference crossings is recorded before and
    after; each reading is polled when psi = 2 pi i / N by the crossings before, and
    carries the instrument's own time stamp. Result: Measurement of kind "tilt" with
    arrays t_s, phi_x_arcsec, phi_y_arcsec, phi_z_arcsec, reference_t_s (station time)
    and values freq_hz (commanded), turns, readings_per_turn, position_deg.
    """

    name: str
    turns: int
    readings_per_turn: int = 12

    @property
    def key(self) -> str:
        return self.name

    def plan(self, ctx: PlanContext) -> tuple[float, Any]:
        ctx.require("gradiometer")
        f = ctx.state.freq_hz
        if f == 0:
            raise ctx.fail("freq_hz", 0.0, "a turning crank (the readings are taken at crank phases)")
        if not 1 <= self.turns <= 100:
            raise ctx.fail("turns", self.turns, "1 .. 100")
        if not 4 <= self.readings_per_turn <= 120:
            raise ctx.fail("readings_per_turn", self.readings_per_turn, "4 .. 120")
        n = self.turns * self.readings_per_turn
        t = np.arange(n) / (self.readings_per_turn * f)
        zeros = np.zeros(n)
        arrays = {"t_s": t, "phi_x_arcsec": zeros, "phi_y_arcsec": zeros, "phi_z_arcsec": zeros,
                  "reference_t_s": np.array([-1.0 / f, (self.turns + 1) / f])}  # fmt: skip
        duration = (2 * CROSSING_CAPTURE_TURNS + self.turns + 1) / f
        return duration, Measurement(self.key, "tilt", self._values(f, ctx.state.position_deg), arrays)

    def _values(self, freq_hz: float, position_deg: float | None) -> dict:
        return {"freq_hz": freq_hz, "turns": self.turns, "readings_per_turn": self.readings_per_turn,
                "position_deg": position_deg}  # fmt: skip

    def run(self, ctx: RunContext) -> Measurement:
        grad = ctx.hw.device("gradiometer")
        period = 1.0 / ctx.freq_hz
        before = ctx.hw.capture_motion(CROSSING_CAPTURE_TURNS * period).reference_t_s
        if not before.size:
            raise DriverError("reference mark monitor", f"no crossing in {CROSSING_CAPTURE_TURNS} turns")
        slot = period / self.readings_per_turn
        readings = []
        first = math.floor((ctx.clock.now_s() - before[-1]) / slot) + 1
        for k in range(first, first + self.turns * self.readings_per_turn):
            ctx.wait_s(before[-1] + k * slot - ctx.clock.now_s())
            readings.append(grad.read())
        after = ctx.hw.capture_motion(CROSSING_CAPTURE_TURNS * period).reference_t_s
        arrays = {"t_s": np.array([r.t_s for r in readings])}
        for axis in AXES:
            arrays[f"phi_{axis}_arcsec"] = np.array([getattr(r, f"phi_{axis}_arcsec") for r in readings])
        arrays["reference_t_s"] = np.concatenate([before, after])
        return Measurement(self.key, "tilt", self._values(ctx.freq_hz, ctx.position_deg), arrays)


def analyse_rotation(session: Session) -> Analysis:
    """Each reading's crank phase from the crossings, then eq. 34 and its least squares (Table 7)."""
    (m, *_) = _of_kind(session, "tilt")
    a = m.arrays
    phase = crank_phase(a["reference_t_s"], 1.0 / m.values["freq_hz"])
    fits = {axis: fit_rotation(axis, a["t_s"], a[f"phi_{axis}_arcsec"], phase) for axis in AXES}
    n = m.values["readings_per_turn"]
    psi = phase.psi_rad(a["t_s"])
    slot_psi = 2 * np.pi * np.arange(n) / n
    slots = {axis: slot_means(psi, a[f"phi_{axis}_arcsec"], n) for axis in AXES}
    offsets = slots["x"][0]
    table7 = []
    for i in range(n):
        psi_deg = float(np.degrees(slot_psi[i]))
        row = {
            "psi_deg": psi_deg,
            "crank_disk_deg": (90.0 - psi_deg) % 360,
            "mean_offset_deg": float(np.degrees(offsets[i])),
        }
        table7.append(row | {f"phi_{axis}_arcsec": float(slots[axis][1][i]) for axis in AXES})
    by_eq34 = {axis: dict(zip(("a0", "as1", "ac1"), eq34(slot_psi, slots[axis][1]), strict=True)) for axis in AXES}
    x = fits["x"]
    comp = {"axs1_rad": x.as1 * ARCSEC_RAD, "axs1_sigma_rad": x.sigma_as1 * ARCSEC_RAD}
    result = {"harmonics": {axis: f.to_json() for axis, f in fits.items()}, "eq34_on_slot_means": by_eq34,
              "table7": table7, "crank_freq_hz": phase.freq_hz, "compensation": comp, "compensation_usage": USAGE,
              "units": "arc-seconds unless the key says otherwise"}  # fmt: skip
    uid = session_uid(session)
    html = rotation_report(f"Session {uid}: parasitic rotation (seed 000 6.1.3)", fits, psi, a, table7, by_eq34)
    summary = "; ".join(f"a{k}s1 = {f.as1:+.3f} ± {f.sigma_as1:.3f}\", a{k}c1 = {f.ac1:+.3f} ± {f.sigma_ac1:.3f}\""
                        for k, f in fits.items())  # fmt: skip
    summary += f"\ncompensation: axs1 = {comp['axs1_rad']:.3e} rad"
    return Analysis({"parasitic_rotation": result}, html, summary)


@procedure("integral_precession.parasitic_rotation",
           "Parasitic rotation of the table top by gradiometer (seed 000 Table 7)", ROTATION_PARAMS,
           analyse=analyse_rotation)  # fmt: skip
def parasitic_rotation(p: dict):
    yield Note(f"gradiometer at {p['readings_per_turn']} crank phases over {p['turns']} turns at {p['freq_hz']:g} Hz")
    yield SetVibration(p["freq_hz"], p["settle_s"])
    yield RecordTilt("tilt", p["turns"], p["readings_per_turn"])
