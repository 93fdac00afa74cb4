"""parasitic_rotation: the table top rocks about x each cycle (seed 000 Table 7, eq. 34).

alpha_x(psi) = ax0 + axs1 sin psi + axc1 cos psi is added to theta_e (physics.md, inputs).
"""

from __future__ import annotations

import numpy as np

from station.twin.effects.base import Effect, Param, Params, Terms
from station.twin.nonlinear_error import ARCSEC_RAD  # arc-second


def motion_angle_rad(p: Params, psi: np.ndarray) -> np.ndarray:
    return p["ax0"] + p["axs1"] * np.sin(psi) + p["axc1"] * np.cos(psi)


EFFECT = Effect(
    name="parasitic_rotation",
    cause="table top rocks about x each cycle (seed 000 Table 7, eq. 34)",
    # seed 000 Table 7: axs1 = -0.92", axc1 = 0.19"; a table top rocking by 1' at most.
    params={
        "ax0": Param("rad"),
        "axs1": Param("rad", typical=4.5e-6, bound=60 * ARCSEC_RAD),
        "axc1": Param("rad", typical=1e-6, bound=60 * ARCSEC_RAD),
    },
    injection={"axs1": -4.46e-6, "axc1": 0.92e-6},  # seed 000 Table 7: -0.92", 0.19"
    notes="ax0 is not fitted: it enters exactly as dtheta_mount (see mount_misalignment)",
    explanation="The table top rocks about the east axis in step with the crank, tilting the input axis by "
    "axs1 sin psi + axc1 cos psi. Measure the rocking with a pair of accelerometers or an autocollimator on the "
    "table top (seed 000 eq. 34) and stiffen or re-shim the guide.",
    separating="a second crank amplitude, or positions half-way between the recorded ones, separate the rocking "
    "from a mount tilt and the index head's angle errors",
    terms=Terms(motion_angle_rad=motion_angle_rad),
    # the static tilt ax0 beside a fitted rocking: the rates fold it into dtheta_mount, the pulse edges see it (the
    # fundamental's in-phase part kz a cos(theta + ax0) is measured to ~1e-7 rad/s)
    pulse_folded=("mount_misalignment", "dtheta_mount"),
)
