"""The terms of a twin's switched-on effects, summed in the registry's order (station.twin.effects.base.Terms).

`effects` is a twin's `TwinConfig.effects` (effect name -> its parameters); an effect that is off adds nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import TypeVar

import numpy as np

from station.twin.effects import EFFECTS
from station.twin.effects.base import Params, Terms

Effects = Mapping[str, Params]
H = TypeVar("H")


def _hooks(effects: Effects, term: Callable[[Terms], H | None]) -> Iterator[tuple[H, Params]]:
    """(hook, parameters) of every switched-on effect that has the term."""
    for name, effect in EFFECTS.items():
        hook = term(effect.terms)
        if hook is not None and name in effects:
            yield hook, effects[name]


def table_harmonics(effects: Effects, w_radps: float) -> list[tuple[int, float, float]]:
    """(j, Zsj, Zcj) of z(t) beyond the nominal A0 sin psi (physics.md, table motion)."""
    return [t for hook, p in _hooks(effects, lambda t: t.table_harmonics) for t in hook(p, w_radps)]


def static_angle_rad(effects: Effects, theta_rad: float) -> float:
    """theta + the angle errors that depend on the position alone (dtheta_idx, dtheta_mount)."""
    angle = theta_rad
    for hook, p in _hooks(effects, lambda t: t.static_angle_rad):
        angle = angle + hook(p, theta_rad)
    return angle


def motion_angle_rad(effects: Effects, psi: np.ndarray) -> np.ndarray:
    """The angle errors over the crank phase (alpha_x), zero without any."""
    alpha = None
    for hook, p in _hooks(effects, lambda t: t.motion_angle_rad):
        alpha = hook(p, psi) if alpha is None else alpha + hook(p, psi)
    return np.zeros_like(psi) if alpha is None else alpha


def lateral_accel_mps2(effects: Effects, psi: np.ndarray, w_radps: float, A0_m: float) -> np.ndarray | None:
    """a_lat, or None without any lateral motion (or at rest)."""
    a_lat = None
    if w_radps:
        for hook, p in _hooks(effects, lambda t: t.lateral_accel_mps2):
            a = hook(p, psi, w_radps, A0_m)
            a_lat = a if a_lat is None else a_lat + a
    return a_lat


def rate_radps(effects: Effects, rate: np.ndarray, a_i: np.ndarray, a_p: np.ndarray, a_o: np.ndarray) -> np.ndarray:
    """The instrument rate with every effect's term added (physics.md, rate model: koq, kx, kip)."""
    for hook, p in _hooks(effects, lambda t: t.rate_radps):
        rate = rate + hook(p, a_i, a_p, a_o)
    return rate


def _scalar(effects: Effects, term: Callable[[Terms], Callable[[Params], float] | None]) -> float:
    return sum((hook(p) for hook, p in _hooks(effects, term)), 0.0)


def frequency_offset(effects: Effects) -> float:
    """eps_f of the true frequency w = w_cmd (1 + eps_f)."""
    return _scalar(effects, lambda t: t.frequency_offset)


def reference_latency_s(effects: Effects) -> float:
    """How late every reference crossing is stamped."""
    return _scalar(effects, lambda t: t.reference_latency_s)


def bias_slope_radps2(effects: Effects) -> float:
    """d of the bias k0 + d t_session."""
    return _scalar(effects, lambda t: t.bias_slope_radps2)
