"""Thermal response of the instrument in seed 001's heat chamber: a first-order lag behind a ramped set point.

The controller ramps its working set point from where it is to the target at the rate limit
(0: a step); the product (the accelerometer and its fixture, where the chamber's product probe
sits) follows the working set point with one time constant. Closed form, so that an emulator
can be asked for any station time and planning can estimate soak times.
"""

from __future__ import annotations

import math

import numpy as np


def ramped_lag(
    t_s: np.ndarray | float, start_c: float, from_c: float, to_c: float, rate_c_per_s: float, tau_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """(product, working set point) t_s after a command: the set point ramps from_c -> to_c at rate_c_per_s
    (0: a step), the product, at start_c when commanded, follows it with time constant tau_s.

    During the ramp u(t) = from + s r t: T = u - s r tau + (start - from + s r tau) e^(-t/tau);
    after it (t > t_r) T relaxes from T(t_r) to the target: T = to + (T(t_r) - to) e^(-(t - t_r)/tau).
    """
    t = np.maximum(np.asarray(t_s, dtype=float), 0.0)
    span = to_c - from_c
    s = math.copysign(1.0, span)
    t_r = abs(span) / rate_c_per_s if rate_c_per_s > 0 else 0.0
    lead = s * rate_c_per_s * tau_s

    def on_ramp(x):
        return from_c + s * rate_c_per_s * x - lead + (start_c - from_c + lead) * np.exp(-x / tau_s)

    at_end = on_ramp(t_r) if t_r > 0 else start_c
    after = to_c + (at_end - to_c) * np.exp(-(t - t_r) / tau_s)
    product = np.where(t <= t_r, on_ramp(np.minimum(t, t_r)), after)
    setpoint = np.where(t <= t_r, from_c + s * rate_c_per_s * t, to_c)
    return product, setpoint


def time_to_band_s(start_c: float, to_c: float, rate_c_per_s: float, tau_s: float, band_c: float) -> float:
    """Station time from a command (product and set point at start_c) until the product is within band_c of to_c:
    the ramp, then the lag left at its end decaying to the band."""
    t_r = abs(to_c - start_c) / rate_c_per_s if rate_c_per_s > 0 else 0.0
    lag = abs(float(ramped_lag(t_r, start_c, start_c, to_c, rate_c_per_s, tau_s)[0]) - to_c)
    return t_r + (tau_s * math.log(lag / band_c) if lag > band_c else 0.0)
