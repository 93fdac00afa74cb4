"""A seed 001 tumble session straight from the model, without the station: for Monte Carlo of the estimators.

The readings of `procedures.tumble.procedure.tumble` in its order (an hour of soak before each temperature,
20 s per reading, the head starting from -45 deg), each the output of eqs. 1 and 4 at its
position, branch and time plus white noise; the chamber's temperature reading carries 0.01 C of
sensor noise. Returns the session and, per temperature, the true eq. 1 coefficients at the
block's mean time (bias drift and launch offset included).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from procedures.tumble.analysis import READING, STEP_DEG, position_deg, stroke_sequence
from station.session import Measurement, Session, StationInfo
from station.twin.pendulous_accelerometer import AccelerometerModel, branch_after_move, cf_coefficients, output_v

SOAK_S = 3600.0
READING_S = 20.0
PV_NOISE_C = 0.01


def tumble_session(
    m: AccelerometerModel,
    temperatures_c: Sequence[float],
    cycles: int,
    sigma_g: float,
    rng: np.random.Generator,
    *,
    head_error_rad: Sequence[float] = (0.0,) * 8,
    voltmeter_gain: float = 0.0,
    voltmeter_offset_v: float = 0.0,
) -> tuple[Session, list[dict[str, float]]]:
    """(session, true coefficients per temperature block); sigma_g is the white noise of one reading.

    head_error_rad: the index head's angle error at 0, 45, .. 315 deg (the head stands at theta + error); the
    voltmeter reads (1 + gain) y + offset (the Type B inputs of procedures.tumble.budget, for its Monte Carlo)."""
    t_s, from_deg, branch = 0.0, -STEP_DEG, 0.0
    launch_g = rng.normal(0.0, m.launch_sigma_g)
    measurements, truths = [], []
    for block, T in enumerate(temperatures_c):
        t_s += SOAK_S
        block_t = []
        for cycle, stroke, J in stroke_sequence(cycles):
            t_s += READING_S
            to_deg = position_deg(J)
            branch = branch_after_move(math.radians(from_deg), math.radians(to_deg), branch)
            error = head_error_rad[round(to_deg / STEP_DEG) % 8]
            volts = output_v(m, math.radians(to_deg) + error, T, branch, launch_g + m.drift_g_per_s * t_s)
            volts += m.scale_v_per_g * rng.normal(0.0, sigma_g)
            volts = (1.0 + voltmeter_gain) * volts + voltmeter_offset_v
            values = {"block": block, "setpoint_c": T, "temperature_c": T + rng.normal(0.0, PV_NOISE_C), "J": J,
                      "stroke": stroke, "cycle": cycle, "position_deg": to_deg, "from_deg": from_deg, "t_s": t_s,
                      "volts": volts}  # fmt: skip
            measurements.append(Measurement(f"T{block + 1}-k{stroke}-J{J}", READING, values))
            block_t.append(t_s)
            from_deg = to_deg
        truths.append(cf_coefficients(m, T, launch_g + m.drift_g_per_s * float(np.mean(block_t))))
    return Session(StationInfo(), [], measurements=measurements), truths
