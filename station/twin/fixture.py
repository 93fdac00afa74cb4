"""The dual-instrument fixture on the indexing head: four orthogonal poses (seed 003 section 4, Figs. 1-3).

Two PIGAs sit on one fixture, their input axes in the head's rotation plane.
Setup 1: PIGA A in pose 1 (0 deg), PIGA B in pose 2 (90 deg); setup 2: A in
pose 4 (270 deg), B in pose 3 (180 deg) (seed 003 eqs. 16-17, 40-41). An
instrument in pose p at head angle theta sees theta_e = theta + dtheta_idx(theta)
+ P_p + its mounting error (physics.md inputs, dtheta_mount), so the head's
angle error is common to both instruments and to every pose.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

from station.twin.config import InstrumentCoefficients, TwinConfig

POSES_DEG: Mapping[int, float] = {1: 0.0, 2: 90.0, 3: 180.0, 4: 270.0}
SETUPS: Mapping[int, tuple[int, int]] = {1: (1, 2), 2: (4, 3)}  # fixture setup -> (pose of A, pose of B)
# Effects that are terms of an instrument's own rate model rather than of the station.
INSTRUMENT_EFFECTS = ("odd_quadratic", "cross_coupling")


def pose_rad(pose: int) -> float:
    """P_p, the nominal angle of pose p from pose 1 about the head axis."""
    return math.radians(POSES_DEG[pose])


def mounted_twin(
    twin: TwinConfig,
    mount_rad: float,
    instrument: InstrumentCoefficients | None = None,
    instrument_effects: Mapping[str, Mapping[str, float]] | None = None,
) -> TwinConfig:
    """The station's twin for an instrument mounted at mount_rad (pose angle plus mounting error).

    With `instrument` (and its own terms in `instrument_effects`), the twin of another
    instrument on the same head: the station's effects (head angle error, earth rate,
    noise) stay, the instrument terms of `twin` are replaced.
    """
    effects = dict(twin.effects)
    if instrument is not None:
        effects = {k: v for k, v in effects.items() if k not in INSTRUMENT_EFFECTS} | dict(instrument_effects or {})
    effects["mount_misalignment"] = {"dtheta_mount": mount_rad}
    return replace(twin, instrument=instrument or twin.instrument, effects=effects)
