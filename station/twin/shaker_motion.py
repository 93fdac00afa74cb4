"""Motion of the electrodynamic shaker's slip table in station time (seed 002 §4).

The seed drives its SINS with sine vibration (0.5-2 g at 10-20 Hz) and random vibration
(0.7 g RMS, flat power spectral density over 10-60 Hz) on an electrodynamic bench. A drive
is a set of spectral lines of the table acceleration along the slip axis,

    a(t) = e(t) sum_k A_k sin(2 pi f_k (t - t_on) + phi_k)

with one line for sine and, for random, a random-phase multisine of equally spaced lines of
equal amplitude (a flat PSD whose RMS over the band is the set RMS). e(t) is the start/stop
ramp, a raised cosine. A linear mount on the table (the rubber dampers of the IMU fixture)
answers each line through its complex gain H(f); under the ramp the answer is taken as
quasi-steady (a ramp lasts many damper time constants), and its derivative is exact for
that product, so that integrating the rate gives back the angle.

`ShakerMotion` is the one table per simulated world (`world.shared("shaker", ShakerMotion)`):
the shaker controller's emulator starts and stops it, the IMU's emulator reads it.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

Gain = Callable[[np.ndarray], np.ndarray]  # frequency (Hz) -> complex gain of a mount on the table


@dataclass(frozen=True)
class Drive:
    """Spectral lines of the table acceleration (m/s^2) and the level the controller regulates."""

    mode: str  # "sine" (level: peak g) or "random" (level: RMS g)
    level_g: float
    freqs_hz: np.ndarray
    amps_mps2: np.ndarray
    phases_rad: np.ndarray


def sine_drive(freq_hz: float, amp_g: float, g_mps2: float) -> Drive:
    """One line of peak amp_g at freq_hz."""
    return Drive("sine", amp_g, np.array([freq_hz]), np.array([amp_g * g_mps2]), np.zeros(1))


def random_drive(
    rms_g: float, lo_hz: float, hi_hz: float, g_mps2: float, rng: np.random.Generator, line_spacing_hz: float = 0.5
) -> Drive:
    """A random-phase multisine with a flat PSD over [lo_hz, hi_hz] and rms_g over the band."""
    freqs = np.arange(lo_hz, hi_hz + line_spacing_hz / 2, line_spacing_hz)
    amp = rms_g * g_mps2 * math.sqrt(2.0 / freqs.size)  # sum of A^2 / 2 is the mean square
    return Drive("random", rms_g, freqs, np.full(freqs.size, amp), rng.uniform(0.0, 2 * math.pi, freqs.size))


def raised_cosine(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ramp 0 -> 1 over x in [0, 1] and its derivative in x."""
    x = np.clip(x, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x), 0.5 * np.pi * np.sin(np.pi * x)


@dataclass(frozen=True)
class ShakerRun:
    """A drive switched on at t_on_s (ramping up over ramp_up_s) and off by its stops, each (t_off_s, ramp_down_s):
    the first ramps it down, a later one only if it brings the table to rest sooner (a trip or an ABORT during a
    ramp-down), the ramps multiplying so that the level stays continuous."""

    drive: Drive
    t_on_s: float
    ramp_up_s: float
    stops: tuple[tuple[float, float], ...] = ()

    @property
    def t_off_s(self) -> float:
        """When the ramp-down began (inf while none was commanded)."""
        return self.stops[0][0] if self.stops else math.inf

    def rest_s(self) -> float:
        """When the table is at rest (inf while no stop was commanded)."""
        return min((t_off_s + ramp_s for t_off_s, ramp_s in self.stops), default=math.inf)

    def envelope(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """e(t) and de/dt."""
        e, de = raised_cosine((t_s - self.t_on_s) / self.ramp_up_s)
        de = de / self.ramp_up_s
        for t_off_s, ramp_s in self.stops:
            down, ddown = raised_cosine((t_s - t_off_s) / ramp_s)
            e, de = e * (1.0 - down), de * (1.0 - down) - e * ddown / ramp_s
        return e, de

    def response(
        self, t_base_s: np.ndarray, offsets_s: np.ndarray, gains: Sequence[Gain | None]
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """y and dy/dt at t_base + offsets, (n, k) each, of mounts with complex gains H(f) per m/s^2 of
        table acceleration (None: the table itself).

        y = Im(sum_k A_k H_k exp(j psi_k)) with psi the lines' phases; the phases on the grid come from
        those at t_base and at the offsets by the angle-sum rule (trigonometry on n + k points, not n k).
        """
        d = self.drive
        w = 2 * np.pi * d.freqs_hz
        base = np.multiply.outer(np.asarray(t_base_s, dtype=float) - self.t_on_s, w) + d.phases_rad
        off = np.multiply.outer(np.asarray(offsets_s, dtype=float), w)
        cb, sb, co, so = np.cos(base)[:, None], np.sin(base)[:, None], np.cos(off), np.sin(off)
        cos_sin = np.concatenate([cb * co - sb * so, sb * co + cb * so], axis=-1)  # (n, k, 2m)
        h = np.stack([d.amps_mps2 * (1.0 if g is None else np.asarray(g(d.freqs_hz), complex)) for g in gains], -1)
        wh = w[:, None] * h
        # Im(e^{j psi} h) = sin psi Re h + cos psi Im h;  Re(e^{j psi} w h) = cos psi Re wh - sin psi Im wh
        coef = np.concatenate([np.hstack([h.imag, wh.real]), np.hstack([h.real, -wh.imag])])  # (2m, 2 gains)
        ys = cos_sin @ coef
        e, de = self.envelope(np.add.outer(np.asarray(t_base_s, dtype=float), offsets_s))
        ng = len(gains)
        return [(e * ys[..., i], de * ys[..., i] + e * ys[..., ng + i]) for i in range(ng)]

    def done(self, t_s: float) -> bool:
        return t_s >= self.rest_s()


class ShakerMotion:
    """The slip table of one simulated world: at most one run at a time; thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._run: ShakerRun | None = None

    def start(self, drive: Drive, t_s: float, ramp_s: float) -> None:
        with self._lock:
            if self._run is not None and not self._run.done(t_s):
                raise RuntimeError("the shaker is already running")
            self._run = ShakerRun(drive, t_s, ramp_s)

    def stop(self, t_s: float, ramp_s: float) -> None:
        """Ramp down from t_s; while ramping down already, only if that brings the table to rest sooner (no effect
        when idle)."""
        with self._lock:
            run = self._run
            if run is not None and t_s >= run.t_on_s and t_s + ramp_s < run.rest_s():
                self._run = replace(run, stops=(*run.stops, (t_s, ramp_s)))

    def phase(self, t_s: float) -> str:
        """idle, ramp_up, run or ramp_down."""
        with self._lock:
            run = self._run
        if run is None or t_s < run.t_on_s or run.done(t_s):
            return "idle"
        if t_s >= run.t_off_s:
            return "ramp_down"
        return "ramp_up" if t_s < run.t_on_s + run.ramp_up_s else "run"

    def moving(self, t_s: float) -> bool:
        return self.phase(t_s) != "idle"

    def response(
        self, t_base_s: np.ndarray, offsets_s: np.ndarray, gains: Sequence[Gain | None]
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """What mounts with gains H see at t_base + offsets (zero while the table rests): (y, dy/dt) per gain."""
        with self._lock:
            run = self._run
        if run is None:
            zero = np.zeros((np.size(t_base_s), np.size(offsets_s)))
            return [(zero, zero) for _ in gains]
        return run.response(t_base_s, offsets_s, gains)

    def max_freq_hz(self) -> float:
        """The highest line of the current drive (0 when there is none)."""
        with self._lock:
            run = self._run
        return 0.0 if run is None else float(run.drive.freqs_hz.max())

    def level_g(self, t_s: float) -> float:
        """The control accelerometer's level: peak g (sine) or RMS g (random), times the ramp."""
        with self._lock:
            run = self._run
        if run is None:
            return 0.0
        return float(run.envelope(np.array([t_s]))[0][0]) * run.drive.level_g
