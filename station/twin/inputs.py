"""Table motion, instrument inputs and the PIGA rate model (physics.md), as pure functions.

psi is the crank phase (rad), w the true angular frequency (rad/s), theta the
commanded indexing position (rad). Accelerations are returned in units of g. The effects' terms come from
their modules (station.twin.effects.terms).
"""

from __future__ import annotations

import numpy as np

from station.twin.config import TwinConfig
from station.twin.effects import terms

ArrayLike = np.ndarray | float


def table_position_m(psi: ArrayLike, w_radps: float, cfg: TwinConfig, zbar_m: float = 0.0):
    """z = zbar + A0 sin psi + sum_j (Zsj sin j psi + Zcj cos j psi)."""
    psi = np.asarray(psi, dtype=float)
    z = zbar_m + cfg.station.A0_m * np.sin(psi)
    for j, zs, zc in terms.table_harmonics(cfg.effects, w_radps):
        if zs:
            z = z + zs * np.sin(j * psi)
        if zc:
            z = z + zc * np.cos(j * psi)
    return z


def table_accel_mps2(psi: ArrayLike, w_radps: float, cfg: TwinConfig):
    """a_z = z''(t) at constant w: -w^2 (A0 sin psi + sum_j j^2 (Zsj sin j psi + Zcj cos j psi))."""
    psi = np.asarray(psi, dtype=float)
    a = cfg.station.A0_m * np.sin(psi)
    for j, zs, zc in terms.table_harmonics(cfg.effects, w_radps):
        if zs:
            a = a + j * j * zs * np.sin(j * psi)
        if zc:
            a = a + j * j * zc * np.cos(j * psi)
    return -(w_radps**2) * a


def effective_angle_rad(theta_rad: float, psi: ArrayLike, cfg: TwinConfig):
    """theta_e = theta + dtheta_idx(theta) + dtheta_mount + alpha_x(psi)."""
    psi = np.asarray(psi, dtype=float)
    return terms.static_angle_rad(cfg.effects, theta_rad) + terms.motion_angle_rad(cfg.effects, psi)


def instrument_inputs(theta_rad: float, psi: ArrayLike, w_radps: float, cfg: TwinConfig):
    """(aI, aP, aO) in g and the earth rate along IA wI in rad/s (physics.md, inputs)."""
    psi = np.asarray(psi, dtype=float)
    g = cfg.station.g_mps2
    theta_e = effective_angle_rad(theta_rad, psi, cfg)
    total = (g + table_accel_mps2(psi, w_radps, cfg)) / g
    a_i = total * np.cos(theta_e)
    a_p = total * np.sin(theta_e)
    a_lat = terms.lateral_accel_mps2(cfg.effects, psi, w_radps, cfg.station.A0_m)
    a_o = np.zeros_like(psi) if a_lat is None else a_lat / g
    if cfg.earth_rate_on:
        w_i = cfg.station.earth_rate_radps * np.sin(cfg.station.latitude_rad - theta_e)
    else:
        w_i = np.zeros_like(psi)
    return a_i, a_p, a_o, w_i


def instrument_rate_radps(theta_rad: float, psi: ArrayLike, w_radps: float, cfg: TwinConfig):
    """w_out without bias drift and noise (physics.md, PIGA rate model)."""
    return rate_from_inputs(instrument_inputs(theta_rad, psi, w_radps, cfg), cfg)


def rate_from_inputs(inputs: tuple, cfg: TwinConfig):
    """The PIGA rate model (physics.md) at the inputs (a_I, a_P, a_O, w_I) of instrument_inputs, which the
    instrument's coefficients do not enter."""
    a_i, a_p, a_o, w_i = inputs
    k = cfg.instrument
    rate = k.k0 + k.kz * a_i + k.kzz * a_i**2 + k.k3 * a_i**3 + k.ky * a_p**2
    return terms.rate_radps(cfg.effects, rate, a_i, a_p, a_o) - w_i
