"""Measurement plans: which points a session measures, in which order (seed 000 5.1-5.2)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from station.twin.measurement import PointSpec

SEED000_FREQS_HZ = (8.0, 9.0, 10.0)
SEED000_PRESET_PULSES = 819_200  # 50 precession revolutions, Tm about 560 s


def equal_angle_positions_deg(n: int) -> list[float]:
    """n positions at equal angles 360 (i - 1) / n (seed 000's 10-position design: n = 10)."""
    return [float(x) for x in np.arange(n) * 360.0 / n]


def multiposition_plan(
    positions_deg: Sequence[float],
    freqs_hz: Sequence[float] = SEED000_FREQS_HZ,
    preset_pulses: int = SEED000_PRESET_PULSES,
) -> list[PointSpec]:
    """At each position the vibration tests, then the static test (seed 000 5.2)."""
    plan: list[PointSpec] = []
    for pos in positions_deg:
        plan += [PointSpec(pos, f, preset_pulses) for f in freqs_hz]
        plan.append(PointSpec(pos, 0.0, preset_pulses))
    return plan


def seed000_plan() -> list[PointSpec]:
    """The embedded default: 10 positions x (8, 9, 10 Hz + static), 40 points, about 6.3 h."""
    return multiposition_plan(equal_angle_positions_deg(10))
