"""A whole seed-002 run of the simulated IMU at once, off line: static, vibration, static.

The IMU's emulator makes the same increments block by block as station time passes; this
makes a run in one call from the same functions, for benchmarks with the seed's 15-minute
alignments and 10-minute vibrations, and for tests of the analysis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.twin.fixture_poses import ROCKING_AXIS_N, SLIP_AXIS_N, FixturePose, mounted
from station.twin.shaker_motion import Drive, ShakerMotion
from station.twin.strapdown_imu import (
    Site,
    StrapdownImuTwin,
    fixture_motion,
    nodes_for,
    sensor_errors,
    true_increments,
)


@dataclass(frozen=True)
class SimulatedRun:
    dt_s: float
    dtheta: np.ndarray  # (N, 3) rad
    dv: np.ndarray  # (N, 3) m/s
    t0_s: float  # vibration commanded, from the first edge
    tk_s: float  # table quiet again


def simulate_run(
    twin: StrapdownImuTwin,
    site: Site,
    pose: FixturePose,
    drive: Drive,
    *,
    rate_hz: float,
    align_s: float,
    vibrate_s: float,
    ramp_s: float,
    rng: np.random.Generator,
    tau: np.ndarray | None = None,
    block_s: float = 10.0,
) -> SimulatedRun:
    """Increments of one run: align_s at rest, ramp up, vibrate_s, ramp down, align_s at rest.

    tau: the true flexure coefficients (default the twin's).
    """
    dt = 1.0 / rate_hz
    motion = ShakerMotion()
    motion.start(drive, align_s, ramp_s)
    t_stop = align_s + ramp_s + vibrate_s
    motion.stop(t_stop, ramp_s)
    tk = t_stop + ramp_s + 1.0
    n = round((tk + align_s) / dt)
    c_bn = mounted(pose, rng.normal(0.0, twin.mount_error_rad, 3))
    true_tau = np.asarray(twin.tau if tau is None else tau)
    k = nodes_for(float(drive.freqs_hz.max()), dt)
    parts_theta, parts_v, theta = [], [], 0.0
    per_block = max(1, round(block_s / dt))
    for start in range(0, n, per_block):
        edges = (np.arange(start, min(start + per_block, n) + 1)) * dt
        m = fixture_motion(motion.response, edges, theta, twin.dampers, k)
        theta = m.theta_end_rad
        d_theta, d_v = true_increments(edges, m, c_bn, SLIP_AXIS_N, ROCKING_AXIS_N, true_tau, site)
        e_theta, e_v = sensor_errors(len(edges) - 1, dt, twin, rng)
        parts_theta.append(d_theta + e_theta)
        parts_v.append(d_v + e_v)
    return SimulatedRun(dt, np.concatenate(parts_theta), np.concatenate(parts_v), align_s, tk)
