"""The IMU fixture's poses on the shaker: the nine vibration directions of seed 002 Fig. 3.

Geometry of this station: the electrodynamic shaker drives a horizontal slip table along the
level frame's east axis u; the L fixture sits on rubber dampers with its centre of gravity
above them, so it rocks about r = up x u (north). A pose is the IMU's attitude C_b^n on the
fixture (the columns are the body axes in ENU).

Only the horizontal components of the attitude error are observed (seed 002 eq. 22), so a
gyro's coefficients are seen only while its axis is horizontal. Each pose puts the products
of eqs. 25-26 that its panel names at their maximum (the vibration along the panel's axis,
the rocking about the axis whose rate multiplies it) with the sensing gyro horizontal. The
nine directions are Fig. 3's: X twice, Y twice, Z twice and the three in-plane diagonals; on
this fixture a diagonal pose rocks about the other diagonal of its plane, so it excites the
pair of tau_ijj of the two gyros in that plane (Fig. 3 pairs them by gyro instead). The
design of the nine poses has rank 12 (tests/methods/test_seed002_analysis.py).
Pose 10 vibrates along the SINS's diagonal, as the seed's random-vibration verification runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.twin.strapdown_imu import rotation_about

SLIP_AXIS_N = np.array([1.0, 0.0, 0.0])  # u: the slip table's axis (east)
ROCKING_AXIS_N = np.array([0.0, 1.0, 0.0])  # r = up x u (north)
UP_N = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class FixturePose:
    number: int
    panel: str  # seed 002 Fig. 3 panel, or "verification"
    vibration: str  # the body direction along the slip axis
    targets: tuple[str, ...]  # flexure coefficients (TAU_NAMES) it observes best
    c_bn: tuple[tuple[float, float, float], ...]  # rows of C_b^n

    @property
    def matrix(self) -> np.ndarray:
        return np.array(self.c_bn)

    def describe(self) -> str:
        fig = f"Fig. 3{self.panel}" if len(self.panel) == 1 else self.panel
        targets = f", for tau_{', tau_'.join(self.targets)}" if self.targets else ""
        return f"pose {self.number} ({fig}): vibration along {self.vibration}{targets}"


def _rows(c_bn: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    """The rows of a 3 x 3 attitude matrix as plain floats."""
    return tuple((float(x), float(y), float(z)) for x, y, z in c_bn)


def _pose(
    number: int, panel: str, vibration: str, targets: tuple[str, ...], axes_n: dict[str, np.ndarray]
) -> FixturePose:
    """A pose from two body axes given in ENU; the third completes the right-handed frame."""
    (a, va), (b, vb) = axes_n.items()
    order = "xyz"
    third = next(c for c in order if c not in (a, b))
    cyclic = (order.index(b) - order.index(a)) % 3 == 1
    cols = {a: va, b: vb, third: np.cross(va, vb) if cyclic else np.cross(vb, va)}
    return FixturePose(number, panel, vibration, targets, _rows(np.column_stack([cols[c] for c in order])))


_S = 1.0 / math.sqrt(2.0)
_DIAG_P, _DIAG_Q = _S * (SLIP_AXIS_N - ROCKING_AXIS_N), _S * (SLIP_AXIS_N + ROCKING_AXIS_N)  # u = (p + q)/sqrt 2
_U, _R = SLIP_AXIS_N, ROCKING_AXIS_N

POSES: dict[int, FixturePose] = {
    p.number: p
    for p in (
        _pose(1, "a", "X", ("xyx",), {"x": _U, "y": _R}),
        _pose(2, "b", "the YZ diagonal", ("yzz", "zyy"), {"y": _DIAG_P, "z": _DIAG_Q}),
        _pose(3, "c", "X", ("xzx",), {"x": _U, "z": _R}),
        _pose(4, "d", "the ZX diagonal", ("zxx", "xzz"), {"z": _DIAG_P, "x": _DIAG_Q}),
        _pose(5, "e", "Y", ("yxy",), {"y": _U, "x": _R}),
        _pose(6, "f", "Y", ("yzy",), {"y": _U, "z": _R}),
        _pose(7, "g", "the XY diagonal", ("xyy", "yxx"), {"x": _DIAG_P, "y": _DIAG_Q}),
        _pose(8, "h", "Z", ("zxz",), {"z": _U, "x": _R}),
        _pose(9, "i", "Z", ("zyz",), {"z": _U, "y": _R}),
    )
}
_BODY_DIAGONAL = np.ones(3) / math.sqrt(3.0)
_ACROSS = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)
POSES[10] = FixturePose(
    10,
    "verification",
    "the SINS's diagonal",
    (),
    _rows(np.array([_BODY_DIAGONAL, _ACROSS, np.cross(_BODY_DIAGONAL, _ACROSS)])),
)
CALIBRATION_POSES = tuple(range(1, 10))


def mounted(pose: FixturePose, error_rad: np.ndarray) -> np.ndarray:
    """C_b^n of the pose as actually mounted: a small rotation error (a rotation vector in ENU) first."""
    angle = float(np.linalg.norm(error_rad))
    if angle == 0.0:
        return pose.matrix
    return rotation_about(np.asarray(error_rad) / angle, np.asarray(angle)) @ pose.matrix
