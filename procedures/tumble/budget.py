"""GUM budget of seed 001's eq. 6 coefficients at one temperature (JCGM 100; seed 001 eqs. 1, 5, 6).

Type A: the stroke fit (levels Y_J, hysteresis, drift) with its n - p dof, through eq. 6. Type B, each
propagated by re-running the stroke fit and eq. 6 on the readings corrected for the input at x +- u
(procedures.common.uncertainty.refit_sources):

- the optical index head's angle error delta_J at each of the eight head angles (J = 9 is J = 1 after a
  full turn: the same angle, the same error): a reading taken at theta_J + delta_J is corrected by the
  exact change of eq. 1, Y(theta_J + delta_J) - Y(theta_J), at the identified coefficients;
- the voltmeter's gain error (y / (1 + e)) and its offset (y - o).

Local g is the unit of the accelerations (aI = cos theta in g), so it does not enter the coefficients in
V/g^n; the chamber's temperature reading places the block on eq. 4's laws and does not enter eq. 6.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from procedures.common.references import Reference, default_references, reference_input
from procedures.common.uncertainty import Budget, Input, fit_budget, refit_sources

HEAD_ANGLES = 8  # distinct head angles of the tumble (J = 1 .. 8; J = 9 is J = 1)


def eq1_output(cf: np.ndarray, theta_rad: np.ndarray) -> np.ndarray:
    """Seed 001 eq. 1 on the tumble (aI = cos theta, aP = sin theta, aO = 0), coefficients K0 .. Mip."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    k0, k1, k2, k3, mo, mip = cf
    return k0 + k1 * c + k2 * c**2 + k3 * c**3 + mo * s + mip * c * s


def corrected_volts(
    volts: np.ndarray, J: np.ndarray, cf: np.ndarray, x: Mapping[str, float], step_rad: float
) -> np.ndarray:
    """The readings as the identification would use them had it known the inputs x (gain, offset, head errors)."""
    theta = (np.asarray(J) - 1) * step_rad
    delta = np.array([x[f"delta_{(j - 1) % HEAD_ANGLES + 1}"] for j in J])
    head = eq1_output(cf, theta + delta) - eq1_output(cf, theta)
    return (volts - x["offset"]) / (1.0 + x["gain"]) - head


def eq6_inputs(refs: Mapping[str, Reference]) -> list[Input]:
    """The Type B inputs of eq. 6: eight head-angle errors, the voltmeter's gain and offset (references file)."""
    head = refs["tumble_head_angle_rad"]
    rows = []
    for j in range(1, HEAD_ANGLES + 1):
        label = f"index head angle error at {(j - 1) * 45:g} deg (J = {j}{', 9' if j == 1 else ''})"
        rows.append(reference_input(f"delta_{j}", label, 0.0, head))
    for key, name, label in (("gain", "voltmeter_gain", "voltmeter gain"),
                             ("offset", "voltmeter_offset_v", "voltmeter offset")):  # fmt: skip
        rows.append(reference_input(key, label, 0.0, refs[name]))
    return rows


def eq6_budget(
    names: tuple[str, ...],
    cf: np.ndarray,
    cf_cov: np.ndarray,
    dof: int,
    units: Mapping[str, str],
    volts: np.ndarray,
    J: np.ndarray,
    refit: Callable[[np.ndarray], np.ndarray],
    references: Mapping[str, Reference] | None = None,
) -> Budget:
    """The budget of eq. 6's K0 .. Mip at one temperature; `refit` maps corrected readings to K0 .. Mip."""
    refs = references if references is not None else default_references()
    step = math.radians(45.0)
    rows = refit_sources(eq6_inputs(refs), lambda x: refit(corrected_volts(volts, J, cf, x, step)))
    return fit_budget(names, cf, cf_cov, dof, units, rows, f"stroke fit (levels, hysteresis, drift), {dof} dof")
