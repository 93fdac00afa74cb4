"""Seed 001: metrological model of an analogue-output navigation pendulous accelerometer (AL-15 class).

Conversion function (seed 001 eq. 1), in volts across the load resistor:

    Y = K0 + K1 aI + K2 aI^2 + K3 aI^3 + Mo aP + Mp aO + Mip aI aP

with every coefficient written through the model of its error (eqs. 2 and 4) at the
instrument's temperature T, dT = T - T0:

    Y = K1(T) [aI + k0(dT) + k0L + k0D t -+ h + k2 aI^2 + k3 aI^3
               + (do + g(dT)) aP + (dp + g(dT)) aO + dip aI aP]
    K1(T) = K1N (1 + b(dT))            b(dT) = beta_T1 dT (dT > 0), beta_T2 dT (dT < 0)
    k0(dT) = k0N + l(dT)               l(dT) = lambda_T1 dT, lambda_T2 dT
    g(dT)  = gamma_T1 dT, gamma_T2 dT

so that K0 = K1(T) k0, K2 = K1(T) k2, Mo = K1(T) do, ... and the seed's k = K / K1 (eq. 6,
last line) are the error-model coefficients at T. The hysteresis -+h of eq. 4 is a loop of
half-width h in the input acceleration (IEEE 1293 tumble hysteresis): the bias reads -h on
the ascending branch (aI last increased) and +h on the descending one. k0L is the
launch-to-launch bias (drawn at power-up), k0D the drift rate (eq. 3); the low-frequency
fluctuations and the threshold are white noise of density `noise_g_rt_hz`.

Tumble (physics.md frames): the indexing head turns about x = OA, so at head angle theta
aI = cos theta, aP = sin theta, aO = 0 (units of local g). A mount tilt in the rotation
plane is not separable from do by the tumble and is left in it.

Defaults are the seed's AL-15 estimates (seed 001, results after eq. 6); gamma_T and dip,
which the seed does not quote, are set to plausible values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Seed 001 results: "k0L ~ +-2e-5 g", "k0D ~ k0F <= +-2e-5 g for 12 hours" (3 sigma).
SEED_HALF_DAY_S = 12 * 3600.0
CF_NAMES = ("K0", "K1", "K2", "K3", "Mo", "Mip")  # seed 001 eq. 1 coefficients, in V/g^n


@dataclass(frozen=True)
class AccelerometerModel:
    """Coefficients of seed 001 eqs. 1, 2 and 4 (accelerations in g, angles in rad, temperatures in deg C)."""

    scale_v_per_g: float = 1.35  # K1N: 1.35 mA/g (AL-15: 1.2 .. 1.5 mA/g) across a 1 kOhm load
    k0_g: float = 3.324e-3  # k0N
    k2_g_per_g2: float = 105e-6
    k3_g_per_g3: float = 87e-6
    delta_o_rad: float = 1.15e-3  # IA towards PA, seen by the tumble about OA
    delta_p_rad: float = 1.15e-3  # IA towards OA (aO = 0 on this tumble)
    delta_ip_per_g: float = 20e-6  # Mip / K1 (not quoted by the seed)
    lambda_above_g_per_c: float = -3.9e-5  # lambda_T1
    lambda_below_g_per_c: float = -4.5e-5  # lambda_T2
    beta_above_per_c: float = 520e-6  # beta_T1
    beta_below_per_c: float = 480e-6  # beta_T2
    gamma_above_rad_per_c: float = 3e-6  # gamma_T1 (not quoted by the seed)
    gamma_below_rad_per_c: float = 2e-6  # gamma_T2 (not quoted by the seed)
    reference_c: float = 20.0  # T0, the temperature of the certified values
    hysteresis_g: float = 3e-4  # h_T
    drift_g_per_s: float = 2e-5 / SEED_HALF_DAY_S  # k0D
    launch_sigma_g: float = 2e-5 / 3  # sigma_L of k0L
    noise_g_rt_hz: float = 16e-6  # white noise density of the output, in g


def bilinear(dT_c: np.ndarray | float, above: float, below: float) -> np.ndarray:
    """Seed 001 eq. 4's temperature laws: `above` dT for dT > 0, `below` dT for dT < 0."""
    dT = np.asarray(dT_c, dtype=float)
    return np.where(dT > 0, above, below) * dT


def tumble_inputs_g(theta_rad: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(aI, aP, aO) in g at head angle theta, the head turning about OA (physics.md frames)."""
    theta = np.asarray(theta_rad, dtype=float)
    return np.cos(theta), np.sin(theta), np.zeros_like(theta)


def cf_coefficients(m: AccelerometerModel, temperature_c: float, bias_extra_g: float = 0.0) -> dict[str, float]:
    """K0 .. Mip of eq. 1 at a temperature (eq. 4); `bias_extra_g` adds launch offset and drift to k0."""
    dT = temperature_c - m.reference_c
    k1 = m.scale_v_per_g * (1.0 + float(bilinear(dT, m.beta_above_per_c, m.beta_below_per_c)))
    k0 = m.k0_g + float(bilinear(dT, m.lambda_above_g_per_c, m.lambda_below_g_per_c)) + bias_extra_g
    delta_o = m.delta_o_rad + float(bilinear(dT, m.gamma_above_rad_per_c, m.gamma_below_rad_per_c))
    return {"K0": k1 * k0, "K1": k1, "K2": k1 * m.k2_g_per_g2, "K3": k1 * m.k3_g_per_g3, "Mo": k1 * delta_o,
            "Mip": k1 * m.delta_ip_per_g}  # fmt: skip


def output_v(
    m: AccelerometerModel,
    theta_rad: np.ndarray | float,
    temperature_c: np.ndarray | float,
    branch: np.ndarray | float = 0.0,
    bias_extra_g: np.ndarray | float = 0.0,
) -> np.ndarray:
    """Noise-free output Y in volts (eqs. 1 and 4); branch +1 ascending, -1 descending, 0 before any input change."""
    aI, aP, aO = tumble_inputs_g(theta_rad)
    dT = np.asarray(temperature_c, dtype=float) - m.reference_c
    k1 = m.scale_v_per_g * (1.0 + bilinear(dT, m.beta_above_per_c, m.beta_below_per_c))
    gamma = bilinear(dT, m.gamma_above_rad_per_c, m.gamma_below_rad_per_c)
    bias = m.k0_g + bilinear(dT, m.lambda_above_g_per_c, m.lambda_below_g_per_c) + bias_extra_g
    bias = bias - m.hysteresis_g * np.asarray(branch, dtype=float)
    error = (bias + m.k2_g_per_g2 * aI**2 + m.k3_g_per_g3 * aI**3 + (m.delta_o_rad + gamma) * aP
             + (m.delta_p_rad + gamma) * aO + m.delta_ip_per_g * aI * aP)  # fmt: skip
    return k1 * (aI + error)


def branch_after_move(from_rad: float, to_rad: float, branch: float) -> float:
    """The hysteresis branch after the head turned monotonically from `from_rad` to `to_rad`.

    aI = cos theta changes direction at multiples of pi, so the last stretch of the move
    (from the last such extremum passed, or from the start) decides: +1 if aI rose on it,
    -1 if it fell; a move that leaves aI unchanged keeps the branch.
    """
    lo, hi = sorted((from_rad, to_rad))
    extrema = np.arange(np.floor(lo / np.pi), np.ceil(hi / np.pi) + 1) * np.pi
    inside = extrema[(extrema > lo + 1e-9) & (extrema < hi - 1e-9)]
    start = from_rad if inside.size == 0 else (inside[-1] if to_rad > from_rad else inside[0])
    change = np.cos(to_rad) - np.cos(start)
    return float(np.sign(change)) if abs(change) > 1e-12 else branch


def noise_sigma_g(m: AccelerometerModel, aperture_s: float) -> float:
    """Standard deviation of the output's white noise averaged over one aperture: density / sqrt(2 T)."""
    return m.noise_g_rt_hz / np.sqrt(2.0 * aperture_s)
