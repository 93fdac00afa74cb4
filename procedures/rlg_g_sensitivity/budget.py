"""GUM budget of seed 002's flexure coefficients tau (eq. 21; JCGM 100), from the runs' stored observations.

Type A: the weighted least squares of eq. 21 (sigma^2 (A^T W A)^-1, n - p dof; W from the reduction's noise,
procedures.rlg_g_sensitivity.analysis.observation_weights). Type B, each by re-solving eq. 21 on the
observations A, B as the run's reduction (eqs. 17-22) would give them at the input x +- u:

- each accelerometer's residual scale factor e_k: the regressor column of tau_ijk holds omega_j f_k, so it
  scales by 1 / (1 + e_k); the alignments' share (their level frame turns with the scaled force, and only
  the horizontal rows of A and B are stored) is left out: against re-reducing scaled increments (tests) the
  sensitivities agree within 17 % of the largest, which is 50 ppm x 1.8 arcsec/g = 1e-4 arcsec/g;
- the IMU's sampling interval dt (1 + e_t): omega and f are increments over dt, so every column of A, a sum of
  omega f dt, scales by 1 / (1 + e_t); the attitudes are sums of angles and do not;
- each gyro's residual bias b (rad/s): the attitude drifts by b T over the vibration, which the two static
  alignments do not see; its east component is a heading error that both alignments take up (as the
  g-sensitive drift at rest, procedures.rlg_g_sensitivity.analysis), so B's north component moves by (C_b^n(t0) b)_N T;
- the site latitude: B holds the attitude error against the Earth's rotation over the vibration (eq. 19),
  B(lam) = B + D C_b^n(t0) [phi(lam) - phi(lam0)] with phi = vee(I - C_b^i(tk) C_i^b(lam)) (eq. 18).

Left out and stated: the gyros' scale factors (they act through the alignments and the attitude history, so
they need the raw increments: about 30 arcsec/g per unit scale error, 1.5e-4 arcsec/g at 5 ppm); local g does
not enter (the reduction uses measured specific force; g only converts arcsec/g, a fixed 9.8 m/s^2).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from procedures.common.references import Reference, default_references, reference_input
from procedures.common.uncertainty import Budget, fit_budget, refit_sources
from procedures.rlg_g_sensitivity.analysis import HORIZONTAL, estimate_flexure, run_weights
from procedures.rlg_g_sensitivity.strapdown import earth_rotation, vee
from station.twin.strapdown_imu import ARCSEC_PER_G, TAU_NAMES, Site

AXES = "xyz"
SEED002_TYPE_B = (
    "Type B by refit of eq. 21 (procedures.rlg_g_sensitivity.budget): accelerometer scale factors, the gyros' residual "
    "biases, the IMU's sampling interval, the site latitude; the gyros' scale factors are not propagated (they "
    "need the raw increments; about 1.5e-4 arcsec/g at 5 ppm)"
)


def column_scale(accel_scale: Sequence[float], clock_rel: float) -> np.ndarray:
    """The factor of each regressor column tau_ijk (omega_j f_k dt) for accelerometer errors e_k and clock e_t."""
    return np.array([1.0 / ((1.0 + accel_scale[AXES.index(n[2])]) * (1.0 + clock_rel)) for n in TAU_NAMES])


def latitude_shift(c_bn_t0: np.ndarray, c_bn_tk: np.ndarray, duration_s: float, site: Site, latitude_rad: float):
    """Change of a run's B (2,) when the reduction takes the latitude as `latitude_rad` instead of the site's."""
    truth = c_bn_tk.T @ earth_rotation(duration_s, site) @ c_bn_t0
    other = c_bn_tk.T @ earth_rotation(duration_s, replace(site, latitude_rad=latitude_rad)) @ c_bn_t0
    return (c_bn_t0 @ -vee(truth.T @ (other - truth)))[HORIZONTAL]


def bias_shift(c_bn_t0: np.ndarray, duration_s: float, bias_radps: np.ndarray) -> np.ndarray:
    """Change of a run's B (east, north) when the reduction removes a gyro bias b from the increments."""
    return np.array([0.0, (c_bn_t0 @ bias_radps)[1] * duration_s])


def flexure_budget(
    runs: Sequence[Mapping],
    site: Site,
    references: Mapping[str, Reference] | None = None,
) -> Budget:
    """The budget of tau (arcsec/g) from the calibration runs' stored values (A, B, c_bn_t0, c_bn_tk, vibration_s,
    align_s)."""
    refs = references if references is not None else default_references()
    A = np.vstack([np.asarray(r["A"], dtype=float) for r in runs])
    B = np.concatenate([np.asarray(r["B"], dtype=float) for r in runs])
    weights = run_weights(runs)
    fit = estimate_flexure(A, B, weights)
    geometry = [(np.asarray(r["c_bn_t0"]), np.asarray(r["c_bn_tk"]), float(r["vibration_s"])) for r in runs]

    def refit(x: Mapping[str, float]) -> np.ndarray:
        scale = column_scale([x[f"accel_{a}"] for a in AXES], x["clock"])
        bias = np.array([x[f"bias_{a}"] for a in AXES])
        shift = np.concatenate([latitude_shift(c0, ck, d, site, x["latitude"]) + bias_shift(c0, d, bias)
                                for c0, ck, d in geometry])  # fmt: skip
        return estimate_flexure(A * scale, B + shift, weights).values / ARCSEC_PER_G

    accel, clock, bias = refs["imu_accel_scale"], refs["imu_clock_rel"], refs["imu_gyro_bias_radps"]
    lat = refs["latitude_deg"]
    inputs = [reference_input(f"accel_{a}", f"accelerometer {a} scale factor", 0.0, accel) for a in AXES]
    inputs += [reference_input(f"bias_{a}", f"gyro {a} residual bias", 0.0, bias) for a in AXES]
    inputs += [
        reference_input("clock", "IMU sampling interval (relative)", 0.0, clock),
        reference_input("latitude", "latitude", site.latitude_rad, lat, u=math.radians(lat.standard_uncertainty),
                        unit="rad"),
    ]  # fmt: skip
    names = TAU_NAMES
    units = dict.fromkeys(names, "arcsec/g")
    return fit_budget(names, fit.values / ARCSEC_PER_G, fit.cov / ARCSEC_PER_G**2, fit.dof, units,
                      refit_sources(inputs, refit), f"eq. 21, {fit.dof} dof")  # fmt: skip
