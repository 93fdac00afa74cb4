"""Measurement plans: which points a session measures, in which order (seed 000 5.1-5.2)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from station import constants
from station.session import PointKind

SEED000_FREQS_HZ = (8.0, 9.0, 10.0)
SEED000_WINDOW_S = 560.0  # seed 000: P = 50 revolutions at 0 deg gives Tm about 560 s
PULSES_PER_REV = 16384


@dataclass(frozen=True)
class PointSpec:
    """One planned point: indexing position, commanded frequency (0 = static), preset count."""

    position_deg: float
    freq_hz: float
    preset_pulses: int = 819_200

    @property
    def kind(self) -> PointKind:
        return "static" if self.freq_hz == 0.0 else "vibration"


def preset_pulses(
    position_deg: float,
    window_s: float = SEED000_WINDOW_S,
    kz_nominal: float = constants.KZ_RADPS_PER_G,
    k0_nominal: float = constants.K0_RADPS,
) -> int:
    """Whole precession revolutions that take about window_s at this position (seed 000 5.1.4).

    The rate is about k0 + kz cos(theta); at least one revolution, so positions
    near 90 and 270 deg still cost hours.
    """
    rate = abs(k0_nominal + kz_nominal * np.cos(np.radians(position_deg)))
    revolutions = max(1, round(rate * window_s / (2 * np.pi)))
    return int(revolutions * PULSES_PER_REV)


def equal_angle_positions_deg(n: int) -> list[float]:
    """n positions at equal angles 360 (i - 1) / n (seed 000's 10-position design: n = 10)."""
    return [float(x) for x in np.arange(n) * 360.0 / n]


def multiposition_plan(
    positions_deg: Sequence[float],
    freqs_hz: Sequence[float] = SEED000_FREQS_HZ,
    window_s: float = SEED000_WINDOW_S,
) -> list[PointSpec]:
    """At each position the vibration tests, then the static test (seed 000 5.2)."""
    plan: list[PointSpec] = []
    for pos in positions_deg:
        preset = preset_pulses(pos, window_s)
        plan += [PointSpec(float(pos), float(f), preset) for f in freqs_hz]
        plan.append(PointSpec(float(pos), 0.0, preset))
    return plan


def point_id(index: int, spec: PointSpec) -> str:
    """The id of the index-th point of a plan, e.g. P007-72deg-v8 or P008-72deg-s."""
    kind = "s" if spec.freq_hz == 0 else f"v{spec.freq_hz:g}"
    return f"P{index + 1:03d}-{spec.position_deg:g}deg-{kind}"


def seed000_plan() -> list[PointSpec]:
    """The embedded default: 10 positions x (8, 9, 10 Hz + static), 40 points, about 6.1 h of windows."""
    return multiposition_plan(equal_angle_positions_deg(10))
