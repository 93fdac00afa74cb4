"""mount_misalignment: the installation tilt in the rotation plane (seed 000 eqs. 25-27), added to theta_e."""

from __future__ import annotations

from station.twin.effects.base import Effect, Param, Params, Terms
from station.twin.nonlinear_error import ARCSEC_RAD  # arc-second


def static_angle_rad(p: Params, theta_rad: float) -> float:
    return p["dtheta_mount"]


EFFECT = Effect(
    name="mount_misalignment",
    cause="installation tilt in the rotation plane (seed 000 eqs. 25-27)",
    # seed 000 5.x: installation errors should stay below 1e-3 rad; 300" at most.
    params={"dtheta_mount": Param("rad", typical=1e-3, bound=300 * ARCSEC_RAD)},
    injection={"dtheta_mount": 1e-3},
    explanation="The instrument sits tilted on the indexing head by dtheta_mount in the rotation plane. Find it by "
    "self-alignment (seed 000 eqs. 25-26) and re-mount or correct the positions.",
    separating="the static rocking (parasitic_rotation's ax0) is the same tilt; nothing separates the two but a "
    "measurement of the table top at rest",
    terms=Terms(static_angle_rad=static_angle_rad),
    aliases=("parasitic_rotation",),  # a constant rocking ax0 enters theta_e exactly as dtheta_mount
)
