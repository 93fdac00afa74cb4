"""Position sequences of a multiposition test on the indexing head (seed 003 5, Figs. 4-7).

Equal angle: theta_i = 360 (i - 1) / n. Equal acceleration: adjacent positions
are 4 / n apart along the path of the input acceleration aI = cos theta once
round the circle (from +1 down to -1 and back up): for even n every step is
|delta aI| = 4 / n, for odd n the step that turns at -1 folds. Positions are whole
counts of the head's encoder, so the angle the station records is the one it sets.
"""

from __future__ import annotations

import numpy as np

from station.twin.plan import equal_angle_positions_deg

SCHEMES = ("equal_angle", "equal_acceleration")
HEAD_COUNTS_PER_DEG = 10_000  # the indexing head's encoder (drivers.indexing_head.driver: 0.0001 deg per count)


def on_head_grid_deg(position_deg: float) -> float:
    """The nearest position the head can take (a whole number of encoder counts), in [0, 360)."""
    return round((position_deg % 360.0) * HEAD_COUNTS_PER_DEG) / HEAD_COUNTS_PER_DEG % 360.0


def equal_acceleration_positions_deg(n: int) -> list[float]:
    """n positions with equal steps of 4/n in aI = cos theta round the circle (seed 003 5, equal acceleration)."""
    s = 4.0 * np.arange(n) / n  # path length travelled in aI from +1
    a = np.where(s <= 2.0, 1.0 - s, s - 3.0)
    half = np.degrees(np.arccos(np.clip(a, -1.0, 1.0)))
    return [float(x) for x in np.where(s <= 2.0, half, 360.0 - half)]


def sequence_deg(scheme: str, n: int) -> list[float]:
    """The n positions of `scheme` on the head's encoder grid."""
    if scheme == "equal_angle":
        raw = equal_angle_positions_deg(n)
    elif scheme == "equal_acceleration":
        raw = equal_acceleration_positions_deg(n)
    else:
        raise ValueError(f"scheme = {scheme!r}: expected one of {', '.join(SCHEMES)}")
    return [on_head_grid_deg(x) for x in raw]
