"""Twin of seed 002's strapdown IMU: an RLG triad with g-sensitive misalignments and a quartz
accelerometer triad, on an L fixture held by rubber dampers on the shaker's slip table.

g-sensitive misalignment (seed 002 eqs. 8-14): the specific force bends each RLG's dither axis,

    omega_tilde = omega + M(f) omega = omega + Gamma(omega, f) tau,

with the twelve flexure coefficients tau (eq. 12) in rad/(m/s^2) and Gamma of eq. 14. The
seed's Table 1 estimates are the simulated IMU's true values.

Rubber-damper rocking (seed 002 §4): the fixture's centre of gravity sits above the dampers,
so table acceleration a(t) along the slip axis u rocks it about r = up x u, a damped rotational
mode driven by -kappa a(t): theta'' + 2 zeta w_r theta' + w_r^2 theta = -kappa a. The rate
about r (tens of deg/s near the 10-20 Hz damper frequency) times the specific force along u
is what makes Gamma tau large. The fixture's translation follows the table through the
dampers' transmissibility.

Frames: the level frame n is the station's ENU (physics.md); the body frame b is the IMU's.
Units: rad, s, m/s^2. Sensor errors besides tau (residual biases after the laboratory
calibration, angle and velocity random walk) are those of a navigation-grade SINS (seed 002 §4).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache

import numpy as np

TAU_NAMES = ("xyx", "xyy", "xzx", "xzz", "yxx", "yxy", "yzy", "yzz", "zxx", "zxz", "zyy", "zyz")  # eq. 12
SEED_G_MPS2 = 9.8  # the seed's "1 g ~ 9.8 m/s^2" in arcsec/g
ARCSEC_RAD = math.pi / 648_000.0
ARCSEC_PER_G = ARCSEC_RAD / SEED_G_MPS2  # 1 arcsec/g in rad/(m/s^2)
DEG_PER_H = math.pi / 180.0 / 3600.0  # 1 deg/h in rad/s
# seed 002 Table 1, arcsec/g, in the order of TAU_NAMES
TABLE1_ARCSEC_PER_G = (0.329, -1.679, -0.418, -1.684, 0.883, 0.511, -0.401, 1.100, -1.353, -0.292, -1.052, 0.237)


def gamma_blocks(omega_b: np.ndarray, f_b: np.ndarray) -> np.ndarray:
    """Gamma_1..3 of seed 002 eq. 14 as (..., 3, 4): gyro i's row times its four coefficients."""
    wx, wy, wz = np.moveaxis(np.asarray(omega_b, dtype=float), -1, 0)
    fx, fy, fz = np.moveaxis(np.asarray(f_b, dtype=float), -1, 0)
    return np.stack(
        [
            np.stack([wy * fx, wy * fy, wz * fx, wz * fz], axis=-1),
            np.stack([wx * fx, wx * fy, wz * fy, wz * fz], axis=-1),
            np.stack([wx * fx, wx * fz, wy * fy, wy * fz], axis=-1),
        ],
        axis=-2,
    )


def gamma_matrix(omega_b: np.ndarray, f_b: np.ndarray) -> np.ndarray:
    """Gamma(t) of seed 002 eq. 14, (..., 3, 12): block diagonal of `gamma_blocks`."""
    blocks = gamma_blocks(omega_b, f_b)
    out = np.zeros((*blocks.shape[:-2], 3, 12))
    for i in range(3):
        out[..., i, 4 * i : 4 * i + 4] = blocks[..., i, :]
    return out


def equivalent_drift(omega_b: np.ndarray, f_b: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """delta omega = M omega = Gamma tau (seed 002 eqs. 11, 13), rad/s, shape (..., 3)."""
    return np.einsum("...ij,ij->...i", gamma_blocks(omega_b, f_b), np.asarray(tau, dtype=float).reshape(3, 4))


def rotation_about(axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrices (..., 3, 3) by angle about a fixed unit axis."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    a = np.asarray(angle_rad, dtype=float)[..., None, None]
    return np.eye(3) + np.sin(a) * k + (1.0 - np.cos(a)) * (k @ k)


@dataclass(frozen=True)
class RubberDampers:
    """The outer rubber dampers under the L fixture (seed 002 §4: natural frequency in 10-20 Hz).

    The defaults reproduce the seed's Fig. 5: at 20 Hz, 1 g of table acceleration rocks the IMU
    at about 36 deg/s, the rate lagging the force by about 3 pi / 5 (eq. 27).
    """

    rocking_hz: float = 14.8
    rocking_damping: float = 0.1
    rocking_radpm: float = 3.83  # kappa = m h / J: rocking acceleration per table acceleration
    translation_hz: float = 45.0
    translation_damping: float = 0.15

    def rocking_gain(self, freq_hz: np.ndarray) -> np.ndarray:
        """Rocking angle about r per table acceleration, rad per m/s^2 (complex)."""
        w, wr = 2 * np.pi * np.asarray(freq_hz, dtype=float), 2 * np.pi * self.rocking_hz
        return -self.rocking_radpm / (wr**2 - w**2 + 2j * self.rocking_damping * wr * w)

    def transmissibility(self, freq_hz: np.ndarray) -> np.ndarray:
        """Fixture acceleration per table acceleration along u (complex)."""
        w, wt = 2 * np.pi * np.asarray(freq_hz, dtype=float), 2 * np.pi * self.translation_hz
        damping = 2j * self.translation_damping * wt * w
        return (wt**2 + damping) / (wt**2 - w**2 + damping)


@dataclass(frozen=True)
class StrapdownImuTwin:
    """The simulated SINS: true flexure coefficients and the sensor errors left after calibration."""

    tau: tuple[float, ...] = tuple(v * ARCSEC_PER_G for v in TABLE1_ARCSEC_PER_G)
    gyro_bias_radps: tuple[float, float, float] = (0.003 * DEG_PER_H, -0.002 * DEG_PER_H, 0.002 * DEG_PER_H)
    gyro_arw_rad_rts: float = 0.0015 * math.pi / 180.0 / 60.0  # 0.0015 deg/sqrt(h)
    accel_bias_mps2: tuple[float, float, float] = (20e-6 * 9.8, -15e-6 * 9.8, 10e-6 * 9.8)
    accel_noise_mps2_rthz: float = 10e-6 * 9.8  # 10 ug/sqrt(Hz)
    mount_error_rad: float = 2e-3  # the fixture's pose errors (no special installation accuracy, seed §4)
    dampers: RubberDampers = field(default_factory=RubberDampers)


@dataclass(frozen=True)
class Site:
    """Where the station is: gravity, Earth rate and latitude (physics.md constants)."""

    g_mps2: float
    earth_rate_radps: float
    latitude_rad: float

    @property
    def earth_rate_n(self) -> np.ndarray:
        """omega_ie in ENU (seed 002 eq. 20)."""
        return self.earth_rate_radps * np.array([0.0, math.cos(self.latitude_rad), math.sin(self.latitude_rad)])


@cache
def legendre_nodes(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes on [0, 1] and weights summing to 1."""
    x, w = np.polynomial.legendre.leggauss(n)
    return (x + 1.0) / 2.0, w / 2.0


def nodes_for(max_freq_hz: float, dt_s: float) -> int:
    """Quadrature nodes per sample interval that integrate lines up to max_freq_hz to ~1e-9."""
    return max(4, math.ceil(1.5 * math.pi * max_freq_hz * dt_s) + 4)


@dataclass(frozen=True)
class FixtureMotion:
    """The fixture's motion over n sample intervals, at k quadrature nodes each (`legendre_nodes`)."""

    theta_rad: np.ndarray  # (n, k) rocking angle about r
    rate_radps: np.ndarray  # (n, k) rocking rate
    accel_mps2: np.ndarray  # (n, k) acceleration along the slip axis u
    theta_change_rad: np.ndarray  # (n,) rocking angle change over each interval
    theta_end_rad: float  # the angle at the last edge


def fixture_motion(
    response: Callable[..., list[tuple[np.ndarray, np.ndarray]]],
    t_edges_s: np.ndarray,
    theta_start_rad: float,
    dampers: RubberDampers,
    n_nodes: int,
) -> FixtureMotion:
    """Sample the table's motion (`ShakerMotion.response`) through the dampers, on evenly spaced edges.

    The angle change of each interval is taken between the edges, the first from theta_start_rad
    (the angle at the first edge when the previous block was made): the gyro increments then add
    up to the angle exactly even when the table's program changed in between (telescoping).
    """
    x, _ = legendre_nodes(n_nodes)
    dt = float(t_edges_s[1] - t_edges_s[0])
    (theta, rate), (accel, _) = response(
        t_edges_s[:-1], np.append(x * dt, dt), (dampers.rocking_gain, dampers.transmissibility)
    )
    change = np.diff(np.concatenate(([theta_start_rad], theta[:, -1])))
    return FixtureMotion(theta[:, :-1], rate[:, :-1], accel[:, :-1], change, float(theta[-1, -1]))


def true_increments(
    t_edges_s: np.ndarray,
    motion: FixtureMotion,
    c_bn_pose: np.ndarray,
    slip_axis_n: np.ndarray,
    rocking_axis_n: np.ndarray,
    tau: np.ndarray,
    site: Site,
) -> tuple[np.ndarray, np.ndarray]:
    """Error-free gyro and accelerometer increments with the g-sensitive drift (eq. 8), (n, 3) each.

    The body attitude is C_b^n(t) = R(r, theta(t)) C_b^n(pose); the rocking part of the gyro
    increment is the angle change along r (exact for a fixed axis), the rest is integrated by
    Gauss-Legendre quadrature over each interval.
    """
    dt = np.diff(t_edges_s)[:, None]
    _, weights = legendre_nodes(motion.theta_rad.shape[1])
    c_nb = np.swapaxes(rotation_about(rocking_axis_n, motion.theta_rad) @ c_bn_pose, -1, -2)  # (n, k, 3, 3)
    rate_n = motion.rate_radps[..., None] * rocking_axis_n + site.earth_rate_n
    omega_b = np.einsum("...ij,...j->...i", c_nb, rate_n)
    f_n = motion.accel_mps2[..., None] * slip_axis_n + np.array([0.0, 0.0, site.g_mps2])
    f_b = np.einsum("...ij,...j->...i", c_nb, f_n)
    earth_b = np.einsum("...ij,j->...i", c_nb, site.earth_rate_n)
    r_b = c_bn_pose.T @ rocking_axis_n
    rest = earth_b + equivalent_drift(omega_b, f_b, tau)
    dtheta = motion.theta_change_rad[:, None] * r_b + dt * np.einsum("k,nki->ni", weights, rest)
    dv = dt * np.einsum("k,nki->ni", weights, f_b)
    return dtheta, dv


def sensor_errors(
    n: int, dt_s: float, twin: StrapdownImuTwin, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Residual bias and random walk of each increment: angle (rad) and velocity (m/s), (n, 3) each."""
    noise = rng.standard_normal((n, 6)) * math.sqrt(dt_s)
    dtheta = np.asarray(twin.gyro_bias_radps) * dt_s + twin.gyro_arw_rad_rts * noise[:, :3]
    dv = np.asarray(twin.accel_bias_mps2) * dt_s + twin.accel_noise_mps2_rthz * noise[:, 3:]
    return dtheta, dv
