"""Crank drive of the linear vibration table: speed ramps and the crank phase psi(t).

The crank phase psi is the table's phase of physics.md (psi = w t + gamma0 in
steady vibration). Commands change the speed with a constant angular
acceleration; the phase is the exact integral of that piecewise-linear speed.
The twin's `frequency_error` effect scales every commanded speed by (1 + eps_f).
"""

from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass

import numpy as np

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class _Segment:
    t_start_s: float
    psi_start_rad: float
    w_start_radps: float
    accel_radps2: float  # signed
    t_ramp_end_s: float
    w_end_radps: float

    def speed_radps(self, t_s: float) -> float:
        if t_s >= self.t_ramp_end_s:
            return self.w_end_radps
        return self.w_start_radps + self.accel_radps2 * (t_s - self.t_start_s)

    def phase_rad(self, t_s: float) -> float:
        tau = min(t_s, self.t_ramp_end_s) - self.t_start_s
        psi = self.psi_start_rad + self.w_start_radps * tau + 0.5 * self.accel_radps2 * tau * tau
        if t_s > self.t_ramp_end_s:
            psi += self.w_end_radps * (t_s - self.t_ramp_end_s)
        return psi


class CrankModel:
    """Crank speed and phase over time; thread-safe, history kept for queries in the past."""

    def __init__(self, eps_f: float = 0.0, psi0_rad: float = 0.0, t0_s: float = 0.0) -> None:
        self.eps_f = float(eps_f)
        self._lock = threading.Lock()
        self._segments: list[_Segment] = [_Segment(t0_s, psi0_rad, 0.0, 0.0, t0_s, 0.0)]
        self._starts: list[float] = [t0_s]

    def _segment_at(self, t_s: float) -> _Segment:
        i = bisect.bisect_right(self._starts, t_s) - 1
        return self._segments[max(i, 0)]

    def command_speed(self, w_cmd_radps: float, accel_radps2: float, t_s: float) -> None:
        """From t_s on, ramp to w_cmd (1 + eps_f) at |accel|; the phase stays continuous."""
        if not accel_radps2 > 0:
            raise ValueError(f"crank acceleration must be > 0 rad/s^2, got {accel_radps2!r}")
        w_target = w_cmd_radps * (1.0 + self.eps_f)
        with self._lock:
            if t_s < self._starts[-1]:
                raise ValueError(f"crank command at {t_s} s precedes the last one at {self._starts[-1]} s")
            seg = self._segment_at(t_s)
            w_now = seg.speed_radps(t_s)
            psi_now = seg.phase_rad(t_s)
            dw = w_target - w_now
            accel = math.copysign(accel_radps2, dw) if dw else 0.0
            t_end = t_s + (abs(dw) / accel_radps2 if dw else 0.0)
            self._segments.append(_Segment(t_s, psi_now, w_now, accel, t_end, w_target))
            self._starts.append(t_s)
            # Old history is never needed beyond a few minutes; keep the list bounded.
            if len(self._segments) > 10_000:
                del self._segments[:5_000]
                del self._starts[:5_000]

    def speed_radps(self, t_s: float) -> float:
        with self._lock:
            return self._segment_at(t_s).speed_radps(t_s)

    def phase_rad(self, t_s: float) -> float:
        """Unwrapped crank phase psi(t_s) in rad."""
        with self._lock:
            return self._segment_at(t_s).phase_rad(t_s)

    def phases_rad(self, t_s: np.ndarray) -> np.ndarray:
        """Vectorised psi(t) for an array of times (any order)."""
        t = np.asarray(t_s, dtype=float)
        with self._lock:
            idx = np.clip(np.searchsorted(self._starts, t, side="right") - 1, 0, None)
            segs = self._segments
            out = np.empty_like(t)
            for i in np.unique(idx):
                sel = idx == i
                seg = segs[i]
                tau = np.minimum(t[sel], seg.t_ramp_end_s) - seg.t_start_s
                psi = seg.psi_start_rad + seg.w_start_radps * tau + 0.5 * seg.accel_radps2 * tau * tau
                out[sel] = psi + seg.w_end_radps * np.maximum(t[sel] - seg.t_ramp_end_s, 0.0)
            return out

    def times_at_phases(self, psi_levels: np.ndarray, t0_s: float, t1_s: float) -> np.ndarray:
        """Times in (t0, t1] at which psi passes each level (the crank turning forwards); exact per segment."""
        levels = np.sort(np.asarray(psi_levels, dtype=float))
        with self._lock:  # only the segments that overlap (t0, t1]: a session's history grows with every command
            first = max(bisect.bisect_right(self._starts, t0_s) - 1, 0)
            last = bisect.bisect_right(self._starts, t1_s)
            bounds = [*self._starts[first + 1 : last + 1], math.inf][: last - first]
            pieces = list(zip(self._segments[first:last], bounds, strict=True))
        out = []
        for seg, seg_end in pieces:
            a, b = max(t0_s, seg.t_start_s), min(t1_s, seg_end)
            if a >= b:
                continue
            # ramp part [a, min(b, ramp end)]: psi = p0 + w0 tau + accel tau^2 / 2, increasing where speed > 0
            ramp_b = min(b, seg.t_ramp_end_s)
            if ramp_b > a:
                lv = levels[(levels > seg.phase_rad(a)) & (levels <= seg.phase_rad(ramp_b))]
                c = seg.psi_start_rad - lv
                if seg.accel_radps2 == 0.0:
                    tau = -c / seg.w_start_radps if seg.w_start_radps > 0 else np.full(lv.size, np.nan)
                else:
                    disc = np.sqrt(np.maximum(seg.w_start_radps**2 - 2 * seg.accel_radps2 * c, 0.0))
                    tau = (-seg.w_start_radps + disc) / seg.accel_radps2
                out.append(seg.t_start_s + tau)
            lin_a = max(a, seg.t_ramp_end_s)
            if b > lin_a and seg.w_end_radps > 0:
                lv = levels[(levels > seg.phase_rad(lin_a)) & (levels <= seg.phase_rad(b))]
                # from the ramp's end, not from a: a crossing's time is the same to the bit whatever interval asks
                p_end = seg.phase_rad(seg.t_ramp_end_s)
                out.append(seg.t_ramp_end_s + (lv - p_end) / seg.w_end_radps)
        if not out:
            return np.zeros(0)
        t = np.concatenate(out)
        return np.sort(t[np.isfinite(t)])

    def at_speed(self, t_s: float) -> bool:
        """True once the current ramp has finished."""
        with self._lock:
            return t_s >= self._segment_at(t_s).t_ramp_end_s

    def ramp_end_s(self, t_s: float) -> float:
        with self._lock:
            return self._segment_at(t_s).t_ramp_end_s
