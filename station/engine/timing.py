"""Integer-period timing capture (physics.md) and its cross-check against the grating record.

From the counter/timer's time stamps: Tm = closing edge - opening edge;
t1 = first reference crossing after the opening; Np = whole periods from t1 to
the first crossing at or after Tm; t2 = that crossing - Tm, in [0, T). The
grating record independently gives the table's frequency and the time of its
upward mid-stroke crossings (psi = 0); a disagreement beyond tolerance is a
fault, not a silent number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station import constants
from station.errors import StationFault


class TimingFault(StationFault):
    """The counter's timing and the grating record disagree, or the window is incomplete."""


@dataclass(frozen=True)
class WindowTiming:
    Tm_s: float
    t1_s: float | None
    t2_s: float | None
    Np: int | None


# Table 4: frequency stability < 5e-4. Counted periods and the grating must agree to that.
FREQ_TOLERANCE_REL = constants.FREQ_STABILITY_MAX
# Consecutive crossings one period apart: a missed one shows as 2 periods, a spurious one as a part of one.
PERIOD_TOLERANCE = 0.1
# A reference crossing and the grating's mid-stroke crossing: the waveform effects of
# Table 5 (Zc1 up to ~0.02 mm of 30 mm) shift the zero crossing by < 1e-3 rad of phase;
# 2e-3 rad of phase (32 us at 10 Hz) is the tolerance.
PHASE_TOLERANCE_RAD = 2e-3


def capture_timing(open_s: float, close_s: float, crossings_s: np.ndarray, freq_hz: float) -> WindowTiming:
    """Tm, t1, t2, Np of one window from its stamps (station seconds)."""
    tm = close_s - open_s
    if not tm > 0:
        raise TimingFault(f"window closed at {close_s} s, not after its opening at {open_s} s")
    if freq_hz == 0:
        return WindowTiming(tm, None, None, None)
    c = np.asarray(crossings_s, dtype=float)
    after_open = c[c > open_s]
    closing = np.flatnonzero(after_open >= close_s)
    if after_open.size == 0 or closing.size == 0:
        raise TimingFault(
            f"{c.size} reference crossings recorded: need one after the opening and one at or after the closing"
        )
    k = int(closing[0])
    t1 = float(after_open[0] - open_s)
    t2 = float(after_open[k] - close_s)
    period = 1.0 / freq_hz
    gaps = np.diff(after_open[: k + 1]) / period
    bad = np.flatnonzero(np.abs(gaps - 1.0) > PERIOD_TOLERANCE)
    if bad.size:
        i = int(bad[0])
        raise TimingFault(
            f"reference crossings {i} and {i + 1} after the opening are {gaps[i]:.3f} periods apart "
            f"(allowed 1 ± {PERIOD_TOLERANCE:g}): missed or spurious reference crossings"
        )
    np_ = k
    counted_hz = np_ / (after_open[k] - after_open[0]) if np_ else float("nan")
    if not abs(counted_hz / freq_hz - 1.0) <= FREQ_TOLERANCE_REL:
        raise TimingFault(
            f"{np_} periods counted between crossings give {counted_hz:.7f} Hz against {freq_hz:g} Hz commanded "
            f"(tolerance {FREQ_TOLERANCE_REL:g} relative): missed or spurious reference crossings"
        )
    if not 0 <= t2 < period * (1 + FREQ_TOLERANCE_REL):
        raise TimingFault(f"t2 = {t2:.6f} s outside [0, T = {period:.6f} s)")
    return WindowTiming(tm, t1, t2, np_)


def grating_phase(t_s: np.ndarray, z_m: np.ndarray, freq_hz: float) -> tuple[float, float, float]:
    """(frequency Hz, amplitude m, time of an upward mid-stroke crossing) from a grating stretch.

    Least squares of z = c + a sin(w t) + b cos(w t), refined once in w by the
    phase drift between the stretch's halves (seed 000 eq. 30, fundamental only).
    """
    t = np.asarray(t_s, dtype=float)
    z = np.asarray(z_m, dtype=float)
    if t.size < 20:
        raise TimingFault(f"grating stretch of {t.size} samples is too short for a phase fit")
    t0 = float(t[0])
    w = 2 * math.pi * freq_hz
    for _ in range(3):
        half = t.size // 2
        phases = []
        for sl in (slice(0, half), slice(half, None)):
            X = np.column_stack([np.ones(t[sl].size), np.sin(w * (t[sl] - t0)), np.cos(w * (t[sl] - t0))])
            _, a, b = np.linalg.lstsq(X, z[sl], rcond=None)[0]
            phases.append(math.atan2(b, a))
        dt = 0.5 * (t[half:].mean() - t[:half].mean()) * 2
        dphi = (phases[1] - phases[0] + math.pi) % (2 * math.pi) - math.pi
        w = w + dphi / dt
    X = np.column_stack([np.ones(t.size), np.sin(w * (t - t0)), np.cos(w * (t - t0))])
    _, a, b = np.linalg.lstsq(X, z, rcond=None)[0]
    phase = math.atan2(b, a)  # z ~ amp sin(w (t - t0) + phase): psi = w (t - t0) + phase
    t_zero = t0 + ((-phase) % (2 * math.pi)) / w
    return w / (2 * math.pi), math.hypot(a, b), t_zero


def cross_check(crossings_s: np.ndarray, grating_t_s: np.ndarray, grating_z_m: np.ndarray, freq_hz: float) -> dict:
    """Compare the counter's reference crossings with the grating's mid-stroke crossings; TimingFault if apart."""
    f_g, amp, t_zero = grating_phase(grating_t_s, grating_z_m, freq_hz)
    if not abs(f_g / freq_hz - 1.0) <= FREQ_TOLERANCE_REL:
        raise TimingFault(f"the grating shows {f_g:.6f} Hz against {freq_hz:g} Hz commanded")
    c = np.asarray(crossings_s, dtype=float)
    if c.size == 0:
        raise TimingFault("no reference crossing to compare with the grating")
    period = 1.0 / f_g
    # phase of each crossing relative to the grating's zero-phase time, wrapped to (-pi, pi]
    phase = 2 * math.pi * ((c - t_zero) / period)
    err = (phase + math.pi) % (2 * math.pi) - math.pi
    nearest = float(err[np.argmin(np.abs(c - t_zero))])
    if abs(nearest) > PHASE_TOLERANCE_RAD:
        raise TimingFault(
            f"reference crossing and grating disagree by {nearest:.2e} rad of phase "
            f"({nearest / (2 * math.pi) * period * 1e6:.1f} us); tolerance {PHASE_TOLERANCE_RAD:g} rad"
        )
    return {"grating_freq_hz": f_g, "grating_amplitude_m": amp, "phase_error_rad": nearest}
