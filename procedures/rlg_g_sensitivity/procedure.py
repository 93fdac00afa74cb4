"""Seed 002: g-sensitive misalignment calibration of a strapdown IMU's RLG triad in linear vibration.

`rlg_g_sensitivity`: the IMU on its L fixture on rubber dampers on the
electrodynamic shaker's slip table; for each fixture pose (the nine vibration directions of
Fig. 3, `station.twin.fixture_poses`) the operator mounts the fixture, then one run: static
alignment, sine vibration in inertial navigation, static realignment (seed 002 Steps 1-3),
reduced to the attitude-error observation of eqs. 17-22. The twelve flexure coefficients
follow by least squares (eq. 21). Verification runs (sine along Y, random along the SINS's
diagonal, seed §4) are then navigated with and without compensation of Gamma tau_hat, the
estimate of the runs before them.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.errors import DriverError, LimitError
from drivers.imu.driver import ImuRecording
from drivers.shaker.envelope import check_ramp, check_random, check_sine
from procedures.rlg_g_sensitivity.analysis import (
    RunRecord,
    least_squares_tau,
    navigate,
    observation_values,
    observe_run,
)
from procedures.rlg_g_sensitivity.report import analyse_session
from station.engine.params import Param
from station.engine.registry import procedure
from station.engine.steps import Checkpoint, Note, OperatorAction, Step
from station.records import Field, declare
from station.session import Measurement
from station.twin.fixture_poses import CALIBRATION_POSES, POSES
from station.twin.strapdown_imu import ARCSEC_PER_G, TAU_NAMES, Site

SETTLE_S = 1.0  # after the ramp down: the dampers ring down in about 0.1 s (1 / zeta w_r)
STATUS_EVERY_S = 1.0  # station seconds between the shaker's status checks during a run
SNIPPET_S = 0.5  # the stretch of rates and forces kept for the report (seed 002 Fig. 5)
# Velocity error as means over 2 s: whole periods of the sine tests and of the controller's random
# frame (lines 0.5 Hz apart), over which the fixture's own velocity averages out.
VELOCITY_BLOCK_S = 2.0


def _site(ctx: Any) -> Site:
    st = ctx.hw.station
    return Site(st.g_mps2, st.earth_rate_radps, st.latitude_rad)


# One run's record (seed 002 eqs. 17-22). The dry run knows the settings and the shapes, not the observation:
# what only a run gives is nullable. A (2 x 12) rad per unit of tau, B (2) rad; verification runs add the navigation.
RUN = declare(
    "seed002_run",
    [Field("role", "str", doc="calibration or verification"), Field("pose", "int64", "", lo=1),
     Field("panel", "str"), Field("mode", "str", doc="sine or random"), Field("level_g", "float64", "g", lo=0.0),
     Field("freq_hz", "float64", "Hz", nullable=True), Field("band_hz", "float64", "Hz", ndim=1),
     Field("align_s", "float64", "s", lo=0.0), Field("vibrate_s", "float64", "s", lo=0.0),
     Field("ramp_s", "float64", "s", lo=0.0), Field("rate_hz", "int64", "Hz", lo=1),
     Field("duration_s", "float64", "s", lo=0.0), Field("tau_hat", "float64", "", ndim=1),
     Field("A", "float64", "rad", ndim=2), Field("B", "float64", "rad", ndim=1),
     Field("c_bn_t0", "float64", "", ndim=2, nullable=True), Field("c_bn_tk", "float64", "", ndim=2, nullable=True),
     Field("mean_products", "float64", "rad/s m/s^2", ndim=2, nullable=True),
     Field("vibration_s", "float64", "s", nullable=True),
     Field("snippet_rate_radps", "float64", "rad/s", ndim=2, nullable=True),
     Field("snippet_force_mps2", "float64", "m/s^2", ndim=2, nullable=True),
     Field("t_s", "float64", "s", ndim=1, nullable=True),
     Field("v_uncompensated_mps", "float64", "m/s", ndim=2, nullable=True),
     Field("v_compensated_mps", "float64", "m/s", ndim=2, nullable=True),
     Field("sensitivity_end", "float64", "", ndim=2, nullable=True),
     Field("decrease_pct", "float64", "%", nullable=True)],
    arrays=[Field("t_s", "float64", "s"), Field("dtheta_rad", "float64", "rad", ndim=2),
            Field("dv_mps", "float64", "m/s", ndim=2)],
    doc="one vibration run of the IMU in one fixture pose (seed 002)",
)  # fmt: skip


@dataclass(frozen=True)
class MountFixture(OperatorAction):
    """Ask the operator to mount the IMU's fixture in a pose (seed 002 Fig. 3)."""

    pose: float = 0

    @classmethod
    def of(cls, pose: float, expected_s: float) -> MountFixture:
        text = POSES[int(pose)].describe() if pose in POSES else f"pose {pose}"
        message = f"Mount the IMU on the L fixture on the shaker in {text}, then confirm."
        return cls(message, (("fixture_pose", int(pose) if pose in POSES else pose),), expected_s, pose)

    def plan(self, ctx):
        if not (self.pose in POSES and float(self.pose).is_integer()):
            raise ctx.fail("fixture_pose", self.pose, f"one of {', '.join(map(str, POSES))}")
        ctx.require("imu")
        dt, _ = super().plan(ctx)
        ctx.state.devices["imu"] = {"pose": int(self.pose)}
        return dt, None


@dataclass(frozen=True)
class VibrationRun(Step):
    """One run of seed 002 Steps 1-3 on the shaker, recorded by the IMU and reduced (eqs. 15-22).

    mode "sine": level_g peak at freq_hz; "random": level_g RMS over band_hz. With tau_hat the run
    is also navigated with and without compensation (a verification run).
    """

    name: str
    pose: int
    mode: str
    level_g: float
    freq_hz: float = 0.0
    band_hz: tuple[float, float] = (0.0, 0.0)
    align_s: float = 900.0
    vibrate_s: float = 600.0
    ramp_s: float = 2.0
    tau_hat: tuple[float, ...] = ()
    raw: bool = False

    @property
    def key(self) -> str:
        return self.name

    @property
    def role(self) -> str:
        return "verification" if self.tau_hat else "calibration"

    def _check_drive(self, section: Any) -> None:
        check_ramp(section, self.ramp_s)
        if self.mode == "sine":
            check_sine(section, self.freq_hz, self.level_g)
        elif self.mode == "random":
            check_random(section, self.level_g, *self.band_hz)
        else:
            raise LimitError("shaker controller", "unknown test", field="mode", value=self.mode,
                             allowed="'sine' or 'random'")  # fmt: skip

    def plan(self, ctx):
        section = ctx.require("shaker")
        if self.mode == "random" and len(self.band_hz) != 2:
            raise ctx.fail("band_hz", list(self.band_hz), "two band edges [lo_hz, hi_hz]")
        imu = ctx.require("imu")
        mounted = ctx.state.devices.get("imu", {}).get("pose")
        if mounted != self.pose:
            raise ctx.fail("fixture_pose", mounted, f"pose {self.pose} mounted first (a MountFixture step)")
        if not 10.0 <= self.align_s <= 7200.0:
            raise ctx.fail("align_s", self.align_s, "10 .. 7200 s")
        if not 1.0 <= self.vibrate_s <= 7200.0:
            raise ctx.fail("vibrate_s", self.vibrate_s, "1 .. 7200 s")
        if self.tau_hat and len(self.tau_hat) != len(TAU_NAMES):
            raise ctx.fail("tau_hat", len(self.tau_hat), f"{len(TAU_NAMES)} flexure coefficients")
        try:
            self._check_drive(section)
        except LimitError as exc:
            raise ctx.fail(exc.field or "mode", exc.value, f"{exc.allowed} (the shaker's envelope)") from None
        duration = 2 * self.align_s + 2 * self.ramp_s + self.vibrate_s + SETTLE_S
        blocks = max(int((self.vibrate_s + 2 * self.ramp_s + SETTLE_S) // VELOCITY_BLOCK_S), 1)
        values = self._values(ctx.state.devices["imu"]["pose"], imu.rate_hz, duration)
        values |= {"A": np.zeros((2, 12)).tolist(), "B": [0.0, 0.0]}
        if self.tau_hat:
            zeros = np.zeros((blocks, 2)).tolist()
            values |= {"t_s": list((np.arange(blocks) + 0.5) * VELOCITY_BLOCK_S), "v_uncompensated_mps": zeros,
                       "v_compensated_mps": zeros, "sensitivity_end": np.zeros((2, 12)).tolist(),
                       "decrease_pct": 0.0}  # fmt: skip
        return duration, Measurement(self.key, "seed002_run", values)

    def _values(self, pose: int, rate_hz: int, duration_s: float) -> dict:
        return {"role": self.role, "pose": pose, "panel": POSES[pose].panel, "mode": self.mode,
                "level_g": self.level_g, "freq_hz": self.freq_hz, "band_hz": list(self.band_hz),
                "align_s": self.align_s, "vibrate_s": self.vibrate_s, "ramp_s": self.ramp_s, "rate_hz": rate_hz,
                "duration_s": duration_s, "tau_hat": list(self.tau_hat)}  # fmt: skip

    def run(self, ctx) -> Measurement:
        imu, shaker = ctx.hw.device("imu"), ctx.hw.device("shaker")
        shaker.check()
        if self.mode == "sine":
            shaker.set_sine(self.freq_hz, self.level_g)
        else:
            shaker.set_random(self.level_g, *self.band_hz)
        rec = ImuRecording(imu.dt_s)
        t0_s, tk_s = self._record(ctx, imu, shaker, rec)
        return self._reduce(ctx, rec, imu.rate_hz, t0_s, tk_s)

    def _reduce(self, ctx: Any, rec: ImuRecording, rate_hz: int, t0_s: float, tk_s: float) -> Measurement:
        """The run's observation (eqs. 17-22) and, for a verification run, its navigation."""
        t_s, dtheta, dv = rec.arrays()
        dt = rec.dt_s
        run = RunRecord.from_times(dtheta, dv, dt, float(t_s[0]) - dt, t0_s, tk_s)
        site = _site(ctx)
        obs = observe_run(run, site)
        values = self._values(self.pose, rate_hz, float(t_s[-1] - t_s[0] + dt))
        mid = (run.i0 + run.ik) // 2
        snip = slice(mid, mid + max(round(SNIPPET_S / dt), 2))
        values |= observation_values(obs) | {"snippet_rate_radps": (dtheta[snip] / dt).tolist(),
                                             "snippet_force_mps2": (dv[snip] / dt).tolist()}  # fmt: skip
        if self.tau_hat:
            nav = navigate(run, site, np.array(self.tau_hat), round(VELOCITY_BLOCK_S * rate_hz))
            values |= {"t_s": nav.t_s.tolist(), "v_uncompensated_mps": nav.v_uncompensated_mps.tolist(),
                       "v_compensated_mps": nav.v_compensated_mps.tolist(),
                       "sensitivity_end": nav.sensitivity[-1].tolist(), "decrease_pct": nav.decrease}  # fmt: skip
        arrays = {"t_s": t_s, "dtheta_rad": dtheta, "dv_mps": dv} if self.raw else {}
        return Measurement(self.key, "seed002_run", values, arrays)

    def _record(self, ctx: Any, imu: Any, shaker: Any, rec: ImuRecording) -> tuple[float, float]:
        """Static, vibration, static: the times the vibration was commanded and the table was quiet again.

        If the run ends early the table is stopped: ramped down after a device's fault, driven off
        at once (ABORT) when the operator aborts or stops the station.
        """
        imu.start_stream()
        running = False
        try:
            rec.add(imu.read_block())
            t_on = rec.last_t_s + self.align_s
            t0_s = t_off = tk_s = t_end = math.inf
            next_check = -math.inf
            while rec.last_t_s < t_end:
                rec.add(imu.read_block())
                ctx.check_abort()
                now = ctx.clock.now_s()
                if t0_s == math.inf and rec.last_t_s >= t_on:
                    t0_s, t_off = now, now + self.ramp_s + self.vibrate_s
                    shaker.start(self.ramp_s)
                    running = True
                    ctx.event("shaker", f"{self.name}: {self._describe()} on")
                elif running and rec.last_t_s >= t_off:
                    shaker.stop(self.ramp_s)
                    running = False
                    tk_s = ctx.clock.now_s() + self.ramp_s + SETTLE_S
                    t_end = tk_s + self.align_s
                    ctx.event("shaker", f"{self.name}: ramped down")
                if running and now >= next_check:
                    st = shaker.check()
                    ctx.publish("shaker", {"key": self.name, "state": st.state, "level_g": st.level_g, "t_s": now})
                    next_check = now + STATUS_EVERY_S
            return t0_s, tk_s
        except BaseException as exc:
            if running:
                self._halt(shaker, at_once=not isinstance(exc, DriverError))
            raise
        finally:
            with contextlib.suppress(DriverError):
                imu.stop_stream()

    def _halt(self, shaker: Any, at_once: bool) -> None:
        """Stop the table after a failed run: a ramp, or the drive off at once; ABORT if the ramp fails."""
        with contextlib.suppress(DriverError):
            if not at_once:
                try:
                    shaker.stop(self.ramp_s)
                    return
                except DriverError:
                    pass
            shaker.abort()

    def _describe(self) -> str:
        if self.mode == "sine":
            return f"sine {self.level_g:g} g at {self.freq_hz:g} Hz"
        return f"random {self.level_g:g} g RMS over {self.band_hz[0]:g}-{self.band_hz[1]:g} Hz"


PARAMS = (
    Param("poses", list, default=list(CALIBRATION_POSES), min=1, max=10,
          help="fixture poses of the calibration runs (1-9: Fig. 3 a-i)"),
    Param("amp_g", float, default=1.5, min=0.05, max=50.0, unit="g", help="sine amplitude (seed: 1.5 g)"),
    Param("freq_hz", float, default=20.0, min=1.0, max=2500.0, unit="Hz",
          help="sine frequency (seed: 20 Hz, near the dampers' natural frequency)"),
    Param("align_s", float, default=900.0, min=10.0, max=7200.0, unit="s",
          help="static alignment before and after each vibration (seed: 15 min)"),
    Param("vibrate_s", float, default=600.0, min=1.0, max=7200.0, unit="s", help="vibration per run (seed: 8-10 min)"),
    Param("ramp_s", float, default=2.0, min=0.1, max=60.0, unit="s", help="the shaker's ramp up and down"),
    Param("verify", bool, default=True, help="verification runs, navigated with and without compensation"),
    Param("verify_sine_poses", list, default=[5.0], min=1, max=10, help="sine verification runs (seed: along Y)"),
    Param("verify_amp_g", float, default=1.0, min=0.05, max=50.0, unit="g", help="their amplitude"),
    Param("verify_freq_hz", float, default=20.0, min=1.0, max=2500.0, unit="Hz", help="their frequency"),
    Param("verify_random_poses", list, default=[10.0], min=1, max=10,
          help="random verification runs (seed: along the SINS's diagonal)"),
    Param("random_rms_g", float, default=0.7, min=0.01, max=20.0, unit="g", help="random level (seed: 0.7 g RMS)"),
    Param("random_band_hz", list, default=[10.0, 60.0], min=1.0, max=2500.0, unit="Hz", help="flat PSD band"),
    Param("remount_s", float, default=300.0, min=0.0, max=3600.0, unit="s", help="operator's time to remount"),
    Param("raw", bool, default=False, help="store every increment of every run"),
)  # fmt: skip


@procedure(
    "rlg_g_sensitivity",
    "RLG g-sensitive misalignment calibration of a strapdown IMU in linear vibration (seed 002)",
    PARAMS,
    analyse=analyse_session,
)
def g_sensitive_misalignment(p: dict):
    common = {"align_s": p["align_s"], "vibrate_s": p["vibrate_s"], "ramp_s": p["ramp_s"], "raw": p["raw"]}
    yield Note(f"{len(p['poses'])} calibration runs: sine {p['amp_g']:g} g at {p['freq_hz']:g} Hz")
    runs = []
    for i, pose in enumerate(p["poses"], 1):
        yield MountFixture.of(pose, p["remount_s"])
        run = VibrationRun(f"cal{i:02d}-pose{pose:g}", int(pose), "sine", p["amp_g"], p["freq_hz"], **common)
        runs.append((yield run))
        yield Checkpoint(f"calibration run {i} done")
    if not p["verify"]:
        return
    tau_hat = least_squares_tau(np.vstack([r.values["A"] for r in runs]), np.concatenate([r.values["B"] for r in runs]))
    listed = ", ".join(f"{n} {v / ARCSEC_PER_G:+.3f}" for n, v in zip(TAU_NAMES, tau_hat, strict=True))
    yield Note(f"verification runs compensated with tau_hat (arcsec/g): {listed}")
    band = tuple(p["random_band_hz"])
    verification = [
        ("sine", pose, p["verify_amp_g"], p["verify_freq_hz"], (0.0, 0.0)) for pose in p["verify_sine_poses"]
    ]
    verification += [("random", pose, p["random_rms_g"], 0.0, band) for pose in p["verify_random_poses"]]
    for i, (mode, pose, level, freq, bandwidth) in enumerate(verification, 1):
        yield MountFixture.of(pose, p["remount_s"])
        yield VibrationRun(f"ver{i:02d}-{mode}-pose{pose:g}", int(pose), mode, level, freq, bandwidth,
                           tau_hat=tuple(float(v) for v in tau_hat), **common)  # fmt: skip
        yield Checkpoint(f"verification run {i} done")
