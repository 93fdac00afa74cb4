"""Seed 002: g-sensitive misalignments of an RLG triad from vibration runs, and their compensation.

A run is one IMU recording: static (Step 1 alignment), vibration from t0 to tk in inertial
navigation, static again (Step 3 realignment). `observe_run` reduces it to the attitude-error
observation of eqs. 17-22, resolved in the level frame at t0 (whose horizontal components D
keeps); `estimate_flexure` is the least squares of eq. 21 with uncertainties;
`navigate` is the pure-inertial velocity error of a run with and without compensation of
Gamma tau_hat (seed 002 §4, Figs. 6-7, Table 2).

One refinement of eq. 17: at rest the IMU also has a g-sensitive drift, gravity times the
Earth's rate. Its east component is indistinguishable from a heading error in static
self-alignment, so both alignments take it up and it never shows in phi_O; it is left out of
A's east row (as navigation leaves it out of the velocity error). The seed keeps it, a
1e-3 part of the observation at 1.5 g and 20 Hz, 1e-2 at 0.5 g.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.linalg

from procedures.rlg_g_sensitivity.strapdown import (
    attitude_error,
    attitude_history,
    coarse_alignment,
    earth_rotation,
    rates_at_stamps,
    rotated_gamma_sums,
)
from station.least_squares import FitError
from station.twin.strapdown_imu import Site, equivalent_drift, gamma_matrix

HORIZONTAL = slice(0, 2)  # D of eq. 22: east and north


@dataclass(frozen=True)
class RunRecord:
    """One run's increments: [0, i0) static, [i0, ik) vibration, [ik, N) static again (edge indices)."""

    dtheta: np.ndarray  # (N, 3) rad
    dv: np.ndarray  # (N, 3) m/s
    dt_s: float
    i0: int
    ik: int

    @classmethod
    def from_times(
        cls, dtheta: np.ndarray, dv: np.ndarray, dt_s: float, t_first_edge_s: float, t0_s: float, tk_s: float
    ) -> RunRecord:
        """Vibration from the edge at or before t0 (commanded) to the edge at or after tk (table quiet again)."""
        i0 = int(np.floor((t0_s - t_first_edge_s) / dt_s + 1e-9))
        ik = int(np.ceil((tk_s - t_first_edge_s) / dt_s))
        if i0 < 1 or ik >= dtheta.shape[0] or ik <= i0:
            raise FitError(f"vibration window [{i0}, {ik}) of {dtheta.shape[0]} increments leaves no static stretch")
        return cls(dtheta, dv, dt_s, i0, ik)

    @cached_property
    def omega(self) -> np.ndarray:
        """Rate at every stamp, band-limited (`rates_at_stamps`)."""
        return rates_at_stamps(self.dtheta, self.dt_s)

    @cached_property
    def force(self) -> np.ndarray:
        """Specific force at every stamp."""
        return rates_at_stamps(self.dv, self.dt_s)

    @property
    def vibration(self) -> slice:
        return slice(self.i0, self.ik)

    @property
    def duration_s(self) -> float:
        return (self.ik - self.i0) * self.dt_s


@dataclass(frozen=True)
class Observation:
    """What one run tells about tau: A tau = B in the level frame's horizontal components."""

    A: np.ndarray  # (2, 12) rad per rad/(m/s^2): D C_b^n(t0) [-int C_b^i Gamma dt], less the east drift at rest
    B: np.ndarray  # (2,) rad: D C_b^n(t0) phi_O^i
    c_bn_t0: np.ndarray  # Step 1 alignment
    c_bn_tk: np.ndarray  # Step 3 realignment
    mean_products: np.ndarray  # (3, 3) <omega_j f_k> over the vibration, (rad/s)(m/s^2) (eqs. 25-26)
    duration_s: float


def observation_values(obs: Observation) -> dict:
    """What a run stores of its observation (the stored values that the budget and the report read)."""
    return {"A": obs.A.tolist(), "B": obs.B.tolist(), "c_bn_t0": obs.c_bn_t0.tolist(), "c_bn_tk": obs.c_bn_tk.tolist(),
            "mean_products": obs.mean_products.tolist(), "vibration_s": obs.duration_s}  # fmt: skip


def static_means(dtheta: np.ndarray, dv: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean rate and specific force of a static stretch of increments."""
    span = dtheta.shape[0] * dt_s
    return dtheta.sum(axis=0) / span, dv.sum(axis=0) / span


def absorbed_east(c_bn_t0: np.ndarray, rate_b: np.ndarray, force_b: np.ndarray) -> np.ndarray:
    """d(east drift at rest)/d tau in the level frame (12,): what the alignments' heading takes up."""
    return (c_bn_t0 @ gamma_matrix(rate_b, force_b))[0]


def observe_run(run: RunRecord, site: Site) -> Observation:
    """The attitude-error observation of one run (seed 002 eqs. 15-22)."""
    vib = run.vibration
    rest = static_means(run.dtheta[: run.i0], run.dv[: run.i0], run.dt_s)
    c_bn_t0 = coarse_alignment(*rest)
    c_bn_tk = coarse_alignment(*static_means(run.dtheta[run.ik :], run.dv[run.ik :], run.dt_s))
    omega, force = run.omega[vib], run.force[vib]
    c_bi = attitude_history(run.dtheta[vib])
    phi_i = attitude_error(c_bi[-1], c_bn_t0, c_bn_tk, run.duration_s, site)
    a_n = c_bn_t0 @ -rotated_gamma_sums(c_bi[1:], omega, force, run.dt_s, run.ik - run.i0)[0]
    a_n[0] += run.duration_s * absorbed_east(c_bn_t0, *rest)
    products = omega.T @ (force - force.mean(axis=0)) / (run.ik - run.i0)
    return Observation(a_n[HORIZONTAL], (c_bn_t0 @ phi_i)[HORIZONTAL], c_bn_t0, c_bn_tk, products, run.duration_s)


@dataclass(frozen=True)
class FlexureFit:
    """tau_hat = (A^T A)^-1 A^T B (eq. 21) with sigma^2 (A^T A)^-1 as its covariance."""

    values: np.ndarray  # rad/(m/s^2), in the order of TAU_NAMES
    cov: np.ndarray
    residuals: np.ndarray  # rad
    sigma_residual: float  # rad
    dof: int
    condition: float  # of A

    @property
    def sigmas(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))


def observation_weights(vibration_s: float, align_s: float) -> np.ndarray:
    """Relative weights of a run's (east, north) observation for eq. 21, from the noise of the reduction.

    Both components carry the gyros' angle random walk over the vibration, variance N^2 T. The east one also
    carries the realignment's heading error, sigma_psi = N / (w_N sqrt(T_a)) (gyrocompassing on the Earth's
    rate w_N over T_a), which the Earth's turn w_N T between t0 and tk puts into the east tilt (the difference
    of the two headings is a turn about the vertical, which D drops): (w_N T sigma_psi)^2 = N^2 T^2 / T_a. So
    var_E / var_N = 1 + T / T_a, whatever N (the seed's 10 min of vibration after 15 of alignment: 1.67). On 100
    simulated sessions (60-s alignments, 30-s vibrations) equal weights gave (tau_hat - tau) / sigma a spread of
    1.53 at 6 dof (t_6: 1.22) and 0.90 coverage of t_6 sigma; these weights 1.26 and 0.94 (twice the east term:
    1.10 and 0.97, over-weighted).
    """
    if not (vibration_s > 0 and align_s > 0):
        raise FitError(f"vibration_s = {vibration_s!r}, align_s = {align_s!r}: both must be > 0 s to weight a run")
    return np.array([1.0 / (1.0 + vibration_s / align_s), 1.0])


def estimate_flexure(A: np.ndarray, B: np.ndarray, weights: np.ndarray | None = None) -> FlexureFit:
    """Least squares of the stacked observations (seed 002 eqs. 21-22), weighted by `weights` (one per row,
    relative: `observation_weights`) when given; sigma is then that of a unit-weight (north) component."""
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    n, p = A.shape
    if n <= p:
        raise FitError(f"{n} attitude-error components cannot fit {p} flexure coefficients: add vibration runs")
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (n,) or not np.all(np.isfinite(w) & (w > 0)):
        raise FitError(f"weights of shape {w.shape}: expected {n} finite positive numbers, one per observation")
    sw = np.sqrt(w)
    tau, _, rank, sv = scipy.linalg.lstsq(A * sw[:, None], B * sw)
    if rank < p:
        raise FitError(f"the runs' design has rank {rank} < {p}: the poses do not observe every coefficient")
    e = B - A @ tau
    sigma = float(np.sqrt(e @ (w * e) / (n - p)))
    cov = sigma**2 * np.linalg.inv(A.T @ (A * w[:, None]))
    return FlexureFit(tau, cov, e, sigma, n - p, float(sv[0] / sv[-1]))


def run_weights(runs: Sequence[Mapping]) -> np.ndarray:
    """`observation_weights` of stored runs (their values' vibration_s and align_s), stacked as eq. 21's rows."""
    return np.concatenate([observation_weights(float(r["vibration_s"]), float(r["align_s"])) for r in runs])


def least_squares_tau(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """tau_hat alone (zeros where the design is empty, as in a dry run): what compensation uses."""
    return scipy.linalg.lstsq(np.asarray(A, dtype=float), np.asarray(B, dtype=float))[0]


@dataclass(frozen=True)
class Navigation:
    """Horizontal velocity error of a run in pure inertial mode, one value per block (seed 002 Figs. 6-7)."""

    t_s: np.ndarray  # block mid-times from t0
    v_uncompensated_mps: np.ndarray  # (n_blocks, 2) east, north
    v_compensated_mps: np.ndarray  # (n_blocks, 2), gyros compensated by Gamma tau_hat
    sensitivity: np.ndarray  # (n_blocks, 2, 12): d v / d tau, m/s per rad/(m/s^2)

    @property
    def decrease(self) -> float:
        """Percentage of velocity error decrease at the end of the run (seed 002 Table 2), 0..100."""
        u, c = np.linalg.norm(self.v_uncompensated_mps[-1]), np.linalg.norm(self.v_compensated_mps[-1])
        return float(100.0 * (1.0 - c / u)) if u > 0 else 0.0


def navigate(run: RunRecord, site: Site, tau_hat: np.ndarray, block: int) -> Navigation:
    """Pure inertial navigation over the vibration from the Step 1 alignment, with and without compensation.

    The velocity is referred to the fixture's mean velocity, zero on the shaker: block means over
    `block` samples (whole vibration periods) leave the error.
    """
    vib, dt = run.vibration, run.dt_s
    omega, force = run.omega[vib], run.force[vib]
    t = (np.arange(run.ik - run.i0) + 1) * dt
    g_n = np.array([0.0, 0.0, -site.g_mps2])
    w_ie = site.earth_rate_n

    def velocity(gyro: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
        rest = static_means(gyro[: run.i0], run.dv[: run.i0], dt)
        c_bn = earth_rotation(t, site) @ coarse_alignment(*rest) @ attitude_history(gyro[vib])[1:]
        f_n = np.einsum("kij,kj->ki", c_bn, force)
        v = np.cumsum(f_n + g_n, axis=0) * dt
        v -= np.cumsum(2.0 * np.cross(w_ie, v), axis=0) * dt  # Coriolis, from the first pass
        nb = v.shape[0] // block
        return v[: nb * block, HORIZONTAL].reshape(nb, block, 2).mean(axis=1), c_bn, rest

    v_u, c_bn, rest = velocity(run.dtheta)
    # The navigation software compensates every sample, the alignment's too.
    v_c, _, _ = velocity(run.dtheta - equivalent_drift(run.omega, run.force, np.asarray(tau_hat, dtype=float)) * dt)
    sensitivity = _sensitivity(c_bn, omega, force, dt, block, absorbed_east(c_bn[0], *rest))
    return Navigation((np.arange(v_u.shape[0]) + 0.5) * block * dt, v_u, v_c, sensitivity)


def _sensitivity(
    c_bn: np.ndarray, omega: np.ndarray, force: np.ndarray, dt_s: float, block: int, absorbed: np.ndarray
) -> np.ndarray:
    """d v^n / d tau at block mid-times: v' = f^n x phi^n, phi^n = -int C_b^n Gamma dt tau (eqs. 16-17),
    less the east drift at rest that the alignment takes up."""
    step = rotated_gamma_sums(c_bn, omega, force, dt_s, block)  # (nb, 3, 12)
    step[:, 0] -= absorbed * block * dt_s
    nb = step.shape[0]
    phi_end = -np.cumsum(step, axis=0)
    phi_mid = phi_end + 0.5 * step
    f_n = np.einsum("kij,kj->ki", c_bn[: nb * block], force[: nb * block]).reshape(nb, block, 3).sum(axis=1) * dt_s
    dv = np.cross(f_n[:, :, None], phi_mid, axis=1)
    s_end = np.cumsum(dv, axis=0)
    return (s_end - 0.5 * dv)[:, HORIZONTAL]
