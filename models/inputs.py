"""Table motion, instrument inputs and the PIGA rate model (physics.md), as pure functions.

psi is the crank phase (rad), w the true angular frequency (rad/s), theta the
commanded indexing position (rad). Accelerations are returned in units of g.
"""

from __future__ import annotations

import numpy as np

from models.config import TwinConfig

ArrayLike = np.ndarray | float


def waveform_terms(w_radps: float, cfg: TwinConfig) -> list[tuple[int, float, float]]:
    """(harmonic j, Zsj, Zcj) of z(t) beyond the nominal A0 sin psi (physics.md, table motion).

    Zs1(w) = z0 + z1 w (seed 000 eq. 32, in metres).
    """
    zs1 = cfg.param("waveform_fundamental", "z0") + cfg.param("waveform_fundamental", "z1") * w_radps
    terms = [(1, zs1, cfg.param("waveform_fundamental", "Zc1"))]
    for j in (2, 3):
        terms.append((j, cfg.param("waveform_harmonics", f"Zs{j}"), cfg.param("waveform_harmonics", f"Zc{j}")))
    return terms


def table_position_m(psi: ArrayLike, w_radps: float, cfg: TwinConfig, zbar_m: float = 0.0):
    """z = zbar + A0 sin psi + sum_j (Zsj sin j psi + Zcj cos j psi)."""
    psi = np.asarray(psi, dtype=float)
    z = zbar_m + cfg.station.A0_m * np.sin(psi)
    for j, zs, zc in waveform_terms(w_radps, cfg):
        if zs:
            z = z + zs * np.sin(j * psi)
        if zc:
            z = z + zc * np.cos(j * psi)
    return z


def table_accel_mps2(psi: ArrayLike, w_radps: float, cfg: TwinConfig):
    """a_z = z''(t) at constant w: -w^2 (A0 sin psi + sum_j j^2 (Zsj sin j psi + Zcj cos j psi))."""
    psi = np.asarray(psi, dtype=float)
    a = cfg.station.A0_m * np.sin(psi)
    for j, zs, zc in waveform_terms(w_radps, cfg):
        if zs:
            a = a + j * j * zs * np.sin(j * psi)
        if zc:
            a = a + j * j * zc * np.cos(j * psi)
    return -(w_radps**2) * a


def index_error_rad(theta_rad: ArrayLike, cfg: TwinConfig):
    """dtheta_idx(theta) = sum_k ck cos k theta + sk sin k theta (physics.md, seed 003)."""
    theta = np.asarray(theta_rad, dtype=float)
    err = np.zeros_like(theta)
    if "index_harmonics" in cfg.effects:
        p = cfg.effects["index_harmonics"]
        for k in range(1, 5):
            err = err + p[f"c{k}"] * np.cos(k * theta) + p[f"s{k}"] * np.sin(k * theta)
    return err


def effective_angle_rad(theta_rad: float, psi: ArrayLike, cfg: TwinConfig):
    """theta_e = theta + dtheta_idx(theta) + dtheta_mount + alpha_x(psi)."""
    psi = np.asarray(psi, dtype=float)
    alpha = (
        cfg.param("parasitic_rotation", "ax0")
        + cfg.param("parasitic_rotation", "axs1") * np.sin(psi)
        + cfg.param("parasitic_rotation", "axc1") * np.cos(psi)
    )
    static = theta_rad + float(index_error_rad(theta_rad, cfg)) + cfg.param("mount_misalignment", "dtheta_mount")
    return static + alpha


def lateral_gain(freq_hz: float, cfg: TwinConfig) -> float:
    """L(f) = L0 / sqrt((1 - (f/fr)^2)^2 + (f/(Q fr))^2)."""
    if "lateral_resonance" not in cfg.effects:
        return 0.0
    p = cfg.effects["lateral_resonance"]
    r = freq_hz / p["fr"]
    return p["L0"] / float(np.sqrt((1.0 - r * r) ** 2 + (r / p["Q"]) ** 2))


def instrument_inputs(theta_rad: float, psi: ArrayLike, w_radps: float, cfg: TwinConfig):
    """(aI, aP, aO) in g and the earth rate along IA wI in rad/s (physics.md, inputs)."""
    psi = np.asarray(psi, dtype=float)
    g = cfg.station.g_mps2
    theta_e = effective_angle_rad(theta_rad, psi, cfg)
    total = (g + table_accel_mps2(psi, w_radps, cfg)) / g
    a_i = total * np.cos(theta_e)
    a_p = total * np.sin(theta_e)
    freq_hz = w_radps / (2.0 * np.pi)
    if "lateral_resonance" in cfg.effects and w_radps:
        phase = cfg.param("lateral_resonance", "phiL")
        a_lat = lateral_gain(freq_hz, cfg) * cfg.station.A0_m * w_radps**2 * np.sin(psi + phase)
        a_o = a_lat / g
    else:
        a_o = np.zeros_like(psi)
    if cfg.earth_rate_on:
        w_i = cfg.station.earth_rate_radps * np.sin(cfg.station.latitude_rad - theta_e)
    else:
        w_i = np.zeros_like(psi)
    return a_i, a_p, a_o, w_i


def instrument_rate_radps(theta_rad: float, psi: ArrayLike, w_radps: float, cfg: TwinConfig):
    """w_out without bias drift and noise (physics.md, PIGA rate model)."""
    a_i, a_p, a_o, w_i = instrument_inputs(theta_rad, psi, w_radps, cfg)
    k = cfg.instrument
    rate = k.k0 + k.kz * a_i + k.kzz * a_i**2 + k.k3 * a_i**3 + k.ky * a_p**2
    if "odd_quadratic" in cfg.effects:
        rate = rate + cfg.param("odd_quadratic", "koq") * a_i * np.abs(a_i)
    if "lateral_resonance" in cfg.effects:
        rate = rate + cfg.param("lateral_resonance", "kx") * a_o**2
    if "cross_coupling" in cfg.effects:
        rate = rate + cfg.param("cross_coupling", "kip") * a_i * a_p
    return rate - w_i
