"""The simulated station's shared physical state, driven by the twin.

One SimStation per simulated station: the clock (all time stamps), the crank
(commanded by the servo emulator), the indexing head, and the instrument's
precession angle. Emulators query it; nothing here talks to a transport.

The instrument model is anchored: at each anchor time the world builds the
twin's closed-form PrecessionWindow for the crank speed and indexing angle
then in force (steady state from the anchor on) and keeps phi continuous
across anchors. It re-anchors whenever the crank or the head was commanded
since the last anchor, and at every window arming (which also draws that
window's rate noise). While the crank ramps, queries re-anchor at the query
time, so edges during a ramp are a piecewise-steady approximation; counter
windows are only armed at constant speed, where the model is exact.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.errors import DriverError
from station.clock import Clock, WallClock
from station.twin.config import TwinConfig, default_twin
from station.twin.crank import CrankModel
from station.twin.effects import terms
from station.twin.inputs import table_position_m
from station.twin.precession import PrecessionWindow, periodic_rate
from station.twin.raw import pulse_edges

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class Window:
    """A counter window: opening and closing pulse-edge times (s) and the signed pulse count."""

    open_s: float
    close_s: float
    pulses: int


@dataclass
class _HeadMove:
    t_start_s: float
    from_deg: float
    to_deg: float
    speed_deg_s: float
    t_stop_s: float = math.inf  # a stop command freezes the head here

    def position_deg(self, t_s: float) -> float:
        t = min(t_s, self.t_stop_s)
        span = self.to_deg - self.from_deg
        travelled = max(t - self.t_start_s, 0.0) * self.speed_deg_s
        if travelled >= abs(span):
            return self.to_deg
        return self.from_deg + math.copysign(travelled, span)

    def busy(self, t_s: float) -> bool:
        if t_s >= self.t_stop_s:
            return False
        return t_s < self.t_start_s + abs(self.to_deg - self.from_deg) / self.speed_deg_s


@dataclass
class _Anchor:
    t_s: float
    window: PrecessionWindow
    phi_rad: float  # absolute precession angle at t_s
    version: int


CROSSINGS_AHEAD_S = 60.0  # reference crossings computed at once (600 at 10 Hz)
CROSSING_MARGIN_S = 1e-6  # far beyond a crossing time's rounding (1e-12 s), far below a period (0.1 s)


class SimStation:
    """Shared state of one simulated station; thread-safe."""

    def __init__(
        self,
        twin: TwinConfig | None = None,
        clock: Clock | None = None,
        seed: int = 0,
        index_speed_deg_s: float = 20.0,
        *,
        sim_lines: bool = False,
        crossings_ahead_s: float = CROSSINGS_AHEAD_S,
    ) -> None:
        self.twin = twin or default_twin()
        self.sim_lines = sim_lines  # serial emulators serve sim:// lines (drivers.sim_serial), else ptys
        self.clock = clock or WallClock()
        self.rng = np.random.default_rng(seed)
        t0 = self.clock.now_s()
        self.crank = _TrackedCrank(self, eps_f=terms.frequency_offset(self.twin.effects), t0_s=t0)
        self.index_speed_deg_s = index_speed_deg_s
        self._lock = threading.RLock()
        self._head = _HeadMove(t0, 0.0, 0.0, index_speed_deg_s)
        self._version = 0
        self._crossings_ahead_s = crossings_ahead_s
        self._crossings: tuple[int, float, float, np.ndarray] | None = None  # version, (t0, t1], stamped times
        self._anchor: _Anchor | None = None
        self._shared: dict[str, Any] = {}
        self._operator_handlers: dict[str, Callable[[Any, float], None]] = {}
        self._head_observers: list[Callable[[float], object]] = []
        self._edge_phase_rad = float(self.rng.uniform(0.0, self.twin.station.pulse_angle_rad))

    # --- state changes -------------------------------------------------------------------
    def attach(self, emulator: Any) -> Any:
        """Start a serial emulator of this world on its kind of line (sim:// or a pty); the emulator."""
        if self.sim_lines:
            emulator.start_sim()
        else:
            emulator.start()
        return emulator

    def _changed(self) -> None:
        with self._lock:
            self._version += 1

    def set_twin(self, twin: TwinConfig) -> None:
        """Change the physics from now on (an emulated device that alters the instrument, e.g. its servo offset)."""
        with self._lock:
            self.twin = twin
        self._changed()

    def on_operator(self, key: str, handler: Callable[[Any, float], None]) -> None:
        """Let a model act when the simulated operator is asked to do `key` (handler(value, t_s))."""
        with self._lock:
            self._operator_handlers[key] = handler

    @property
    def operator(self) -> SimOperator:
        return SimOperator(self)

    def shared(self, name: str, factory: Callable[[], Any]) -> Any:
        """One model per world under `name` (a chamber's temperature, a shaker's motion), made on first use,
        so that the emulators of several devices see the same physical thing."""
        with self._lock:
            if name not in self._shared:
                self._shared[name] = factory()
            return self._shared[name]

    # --- table -----------------------------------------------------------------------------
    def table_position_m(self, t_s: np.ndarray) -> np.ndarray:
        """Absolute grating position z(t) in metres (physics.md table motion, waveform effects on)."""
        t = np.asarray(t_s, dtype=float)
        psi = self.crank.phases_rad(t)
        w = self.crank.speed_radps(float(t.mean())) if t.size else 0.0
        return table_position_m(psi, w, self.twin)

    def reference_crossings_s(self, t0_s: float, t1_s: float) -> np.ndarray:
        """Times of psi = 0 mod 2 pi crossings in (t0, t1], as stamped (read-head latency included).

        Computed crossings_ahead_s at a time and kept until the world changes (a crank command, a new twin):
        the counter asks four times a second, and each crossing's time does not depend on the interval."""
        with self._lock:
            cached = self._crossings
            if cached is None or cached[0] != self._version or not cached[1] <= t0_s <= t1_s <= cached[2]:
                t_end_s = max(t1_s, t0_s + self._crossings_ahead_s)
                # the stamped time alone decides which interval a crossing falls in: computed with a margin,
                # none is lost to a last-bit difference between a crossing's phase and its time at an end
                found = self._crossings_s(t0_s - CROSSING_MARGIN_S, t_end_s + CROSSING_MARGIN_S)
                cached = self._crossings = (self._version, t0_s, t_end_s, found)
        times = cached[3]
        return times[np.searchsorted(times, t0_s, side="right") : np.searchsorted(times, t1_s, side="right")]

    def _crossings_s(self, t0_s: float, t1_s: float) -> np.ndarray:
        latency = terms.reference_latency_s(self.twin.effects)
        a, b = t0_s - latency, t1_s - latency
        p_a, p_b = self.crank.phase_rad(a), self.crank.phase_rad(b)
        # One level beyond each end: times_at_phases decides each level exactly against the crank's segment,
        # whose phase at an end may differ from phase_rad's in the last bit (a crossing on an end was lost).
        levels = TWO_PI * np.arange(math.floor(p_a / TWO_PI), math.floor(p_b / TWO_PI) + 2)
        return self.crank.times_at_phases(levels, a, b) + latency

    def table_moving(self, t_s: float) -> bool:
        return self.crank.speed_radps(t_s) != 0.0

    # --- indexing head -----------------------------------------------------------------------
    def on_head_move(self, observer: Callable[[float], object]) -> None:
        """Call observer(t_s) whenever the head is commanded, before the new move: between two calls it turns
        one way only, so an observer that reads the head at each call sees the path it turned, read or not."""
        with self._lock:
            self._head_observers.append(observer)

    def index_command_move(self, target_deg: float, t_s: float) -> None:
        with self._lock:
            for observer in self._head_observers:
                observer(t_s)
            here = self._head.position_deg(t_s)
            self._head = _HeadMove(t_s, here, float(target_deg), self.index_speed_deg_s)
        self._changed()

    def index_stop(self, t_s: float) -> None:
        with self._lock:
            self._head.t_stop_s = min(self._head.t_stop_s, t_s)
        self._changed()

    def index_position_deg(self, t_s: float) -> float:
        """The head's encoder reading."""
        with self._lock:
            return self._head.position_deg(t_s)

    def index_busy(self, t_s: float) -> bool:
        with self._lock:
            return self._head.busy(t_s)

    # --- instrument output -----------------------------------------------------------------------
    def _make_window(self, t_s: float, draw_noise: bool, preset_pulses: int = 819_200) -> PrecessionWindow:
        # The encoder angle: the twin adds the head's angle error and the mount tilt itself.
        theta = math.radians(self.index_position_deg(t_s))
        w = self.crank.speed_radps(t_s)
        rate = periodic_rate(theta, w / TWO_PI, self.twin)
        offset = 0.0
        noise = self.twin.noise
        if draw_noise and noise.rate_noise_radps > 0:
            tm_est = preset_pulses * self.twin.station.pulse_angle_rad / max(abs(rate.c0_radps), 1e-12)
            offset = self.rng.normal(0.0, noise.rate_noise_radps * math.sqrt(noise.rate_noise_ref_s / tm_est))
        gamma0 = self.crank.phase_rad(t_s) % TWO_PI
        return PrecessionWindow(rate, w, gamma0, offset, terms.bias_slope_radps2(self.twin.effects), t_s)

    def _anchor_at(
        self, t_s: float, *, force: bool = False, draw_noise: bool = False, preset_pulses: int = 819_200
    ) -> _Anchor:
        with self._lock:
            a = self._anchor
            ramping = not self.crank.at_speed(t_s)
            if a is not None and not force and a.version == self._version and not ramping and t_s >= a.t_s:
                return a
            phi = 0.0 if a is None else a.phi_rad + float(a.window.phi_rad(t_s - a.t_s))
            offset_kept = a.window.offset_radps if a is not None and not draw_noise else 0.0
            win = self._make_window(t_s, draw_noise, preset_pulses)
            if not draw_noise and offset_kept:
                win = PrecessionWindow(
                    win.rate, win.w_radps, win.gamma0_rad, offset_kept, win.drift_radps2, win.t0_session_s
                )
            self._anchor = _Anchor(t_s, win, phi, self._version)
            return self._anchor

    def pulse_edges_s(self, t0_s: float, t1_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Every output pulse edge in (t0, t1]: times and directions (+1 up, -1 down)."""
        a = self._anchor_at(t0_s)
        q = self.twin.station.pulse_angle_rad
        offset = (a.phi_rad + self._edge_phase_rad) % q
        times, dirs = pulse_edges(a.window, t1_s - a.t_s, q, phase_offset_rad=offset)
        keep = times > t0_s - a.t_s
        return times[keep] + a.t_s, dirs[keep]

    def open_window(self, t_arm_s: float, preset_pulses: int) -> Window:
        """The counter window armed at t_arm: it opens on the next pulse edge and closes P edges later."""
        if preset_pulses <= 0:
            raise ValueError(f"preset pulse count must be > 0, got {preset_pulses}")
        a = self._anchor_at(t_arm_s, force=True, draw_noise=True, preset_pulses=preset_pulses)
        span = 1.0
        while True:
            times, _ = self.pulse_edges_s(t_arm_s, t_arm_s + span)
            if times.size:
                break
            span *= 4.0
            if span > 1e7:
                raise RuntimeError("the instrument gives no output pulse: its rate is zero")
        t_open = float(times[0])
        w = a.window
        gamma_open = (w.gamma0_rad + w.w_radps * (t_open - a.t_s)) % TWO_PI
        from_open = PrecessionWindow(w.rate, w.w_radps, gamma_open, w.offset_radps, w.drift_radps2, t_open)
        tm = from_open.first_passage_s(preset_pulses * self.twin.station.pulse_angle_rad)
        sign = 1 if from_open.mean_rate_radps >= 0 else -1
        return Window(t_open, t_open + tm, sign * preset_pulses)


class SimOperator:
    """The simulated station's operator: does at once what an OperatorAction asks, through the world's handlers."""

    def __init__(self, world: SimStation) -> None:
        self.world = world

    def perform(self, message: str, action: dict[str, Any]) -> None:
        handlers = self.world._operator_handlers
        unknown = [k for k in action if k not in handlers]
        if unknown:
            raise DriverError(
                "simulated operator", f"cannot do {unknown} (asked: {message!r})", allowed=", ".join(sorted(handlers))
            )
        t_s = self.world.clock.now_s()
        for key, value in action.items():
            handlers[key](value, t_s)
        self.world._changed()


class _TrackedCrank(CrankModel):
    """The crank, telling the world when it is commanded (the instrument model re-anchors)."""

    def __init__(self, world: SimStation, eps_f: float, t0_s: float) -> None:
        super().__init__(eps_f=eps_f, t0_s=t0_s)
        self._world = world

    def command_speed(self, w_cmd_radps: float, accel_radps2: float, t_s: float) -> None:
        super().command_speed(w_cmd_radps, accel_radps2, t_s)
        self._world._changed()
