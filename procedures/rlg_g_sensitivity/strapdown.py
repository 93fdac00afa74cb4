"""Strapdown computations on recorded IMU increments (seed 002 §3): alignment, attitude, navigation.

Increments are interval integrals: sample k holds the angle and velocity increments over
(t_k - dt, t_k]. `rates_at_stamps` recovers the band-limited rate and specific force at the
stamps t_k by undoing the interval mean in the frequency domain (the mean over an interval is
a filter sinc(f dt) exp(-j pi f dt)); products of such signals summed at the stamps carry no
aliasing into their slowly varying part as long as their total bandwidth stays below the
sample rate, which is what makes the attitude-error regressors (eq. 17) and the navigated
velocity right under 10-60 Hz vibration sampled at 200 Hz, without a coning or sculling
algorithm of some order.

Frames: n is the station's ENU; i = b(t0), the body frame at the start of the vibration,
fixed in inertial space (seed 002 eq. 15).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from station.twin.strapdown_imu import Site, gamma_blocks, rotation_about


def coarse_alignment(mean_rate_b: np.ndarray, mean_force_b: np.ndarray) -> np.ndarray:
    """Static self-alignment (seed 002 Steps 1 and 3): C_b^n from gravity and the Earth's rate.

    Up is along the mean specific force, east along omega_ie x up, north completes ENU.
    """
    up = mean_force_b / np.linalg.norm(mean_force_b)
    east = np.cross(mean_rate_b, up)
    east /= np.linalg.norm(east)
    return np.vstack([east, np.cross(up, east), up])


def rates_at_stamps(increments: np.ndarray, dt_s: float) -> np.ndarray:
    """The signal at each stamp from its interval integrals (N, 3), band-limited below Nyquist."""
    n = increments.shape[0]
    spectrum = np.fft.rfft(increments / dt_s, axis=0)
    f = np.fft.rfftfreq(n, dt_s)
    spectrum *= (np.exp(1j * np.pi * f * dt_s) / np.sinc(f * dt_s))[:, None]
    if n % 2 == 0:
        spectrum[-1] = 0.0  # the Nyquist line has no phase to undo
    return np.fft.irfft(spectrum, n, axis=0)


def attitude_history(dtheta: np.ndarray) -> np.ndarray:
    """C_b^i at the N + 1 edges of N gyro increments, C_b^i = I at the first (seed 002 eq. 15).

    Each increment's rotation vector carries the two-sample coning term; the running product is
    a parallel prefix product of quaternions (log2 N vectorised passes).
    """
    phi = dtheta.copy()
    phi[1:] += np.cross(dtheta[:-1], dtheta[1:]) / 12.0
    q = np.vstack([[0.0, 0.0, 0.0, 1.0], Rotation.from_rotvec(phi).as_quat()])
    step = 1
    while step < len(q):
        q[step:] = quaternion_product(q[:-step], q[step:])
        step *= 2
    return Rotation.from_quat(q).as_matrix()


def quaternion_product(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton products p q of (N, 4) scalar-last quaternions (scipy's order): the rotation q, then p.

    On plain arrays: scipy's Rotation composes each pair through its own objects (`attitude_history` of 120 000
    increments: 2.4 s with it, 0.4 s without; BENCHMARKS.md)."""
    pv, pw = p[:, :3], p[:, 3:]
    qv, qw = q[:, :3], q[:, 3:]
    return np.hstack([pw * qv + qw * pv + np.cross(pv, qv), pw * qw - np.sum(pv * qv, axis=1, keepdims=True)])


def earth_rotation(duration_s: np.ndarray | float, site: Site) -> np.ndarray:
    """C_{n(t0)}^{n(t)}: the level frame turned by the Earth over duration_s (seed 002 eq. 20)."""
    w = site.earth_rate_n
    return rotation_about(w / np.linalg.norm(w), -np.linalg.norm(w) * np.asarray(duration_s, dtype=float))


def vee(skew: np.ndarray) -> np.ndarray:
    """The vector of the antisymmetric part of a 3 x 3 matrix."""
    a = 0.5 * (skew - skew.T)
    return np.array([a[2, 1], a[0, 2], a[1, 0]])


def attitude_error(c_bi_end: np.ndarray, c_bn_t0: np.ndarray, c_bn_tk: np.ndarray, duration_s: float, site: Site):
    """phi_O^i (seed 002 eq. 18): computed attitude against the true one of eq. 19 from the two alignments."""
    c_ib_true = c_bn_tk.T @ earth_rotation(duration_s, site) @ c_bn_t0
    return vee(np.eye(3) - c_bi_end @ c_ib_true)


def rotated_gamma_sums(c: np.ndarray, omega_b: np.ndarray, f_b: np.ndarray, dt_s: float, block: int) -> np.ndarray:
    """sum of C(t) Gamma(t) dt over consecutive blocks of `block` stamps: (n_blocks, 3, 12) (eq. 17).

    A trailing partial block is left out.
    """
    nb = c.shape[0] // block
    m = nb * block
    g = gamma_blocks(omega_b[:m], f_b[:m]).reshape(nb, block, 3, 4)
    sums = np.einsum("bkji,bkil->bjil", c[:m].reshape(nb, block, 3, 3), g) * dt_s
    return sums.reshape(nb, 3, 12)
